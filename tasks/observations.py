"""The navigation task's observables: the robot's and the wire's joint features, the top
view's images, and the extra signals a task can enable one by one.

Which of them an environment returns is an observation preset's choice
(`cathsim_dmc.tasks.presets.OBSERVATION_PRESETS`) plus `extra_observations`.
"""

from __future__ import annotations

import numpy as np
from dm_control.composer.observation import observable

from cathsim_dmc.core.registry import EXTRA_OBSERVATIONS
from cathsim_dmc.sim import detector, raster
from cathsim_dmc.sim.render import ObservationSettings, TopView, image_noise
from cathsim_dmc.tasks.roadmap import DEPTH_CLOCK_STEPS, RoadmapTracker
from cathsim_dmc.tasks.tracking2d import ImageTracker


def check_extra_observations(extra_observations) -> tuple:
    """`extra_observations` as a tuple; ValueError naming any that is unknown."""
    unknown = sorted(set(extra_observations) - set(EXTRA_OBSERVATIONS))
    if unknown:
        raise ValueError(f"extra_observations {unknown} unknown; choose from {list(EXTRA_OBSERVATIONS)}")
    return tuple(extra_observations)


def task_observables(
    task, settings: ObservationSettings, extra_observations: tuple = ()
) -> tuple[dict, TopView, RoadmapTracker, ImageTracker]:
    """(name -> observable, the `TopView` drawing the images, the `RoadmapTracker` of the
    roadmap observation, the `ImageTracker` of the image-plane observations) for `task`
    (a `Navigate`), those of `settings` and `extra_observations` enabled."""
    robot, guidewire = task.robot, task.guidewire
    wire_joints = guidewire.joints
    top_view = TopView(
        settings.image_size, renderer=settings.renderer, wire=guidewire, vessel_geom_id=task.aorta.visual_geom_id
    )
    roadmap = RoadmapTracker(task, settings.tracking_noise_m, settings.registration_error_m)
    fluoro_frame = None
    if settings.tracking_source == "fluoro_image":
        corrupt = detector_frame(top_view, settings)

        def fluoro_frame(physics, random_state):
            return corrupt(top_view.image(physics, "fluoro"), random_state)

    image_tracker = ImageTracker(task, settings.tracking_noise_m, frame=fluoro_frame)

    def catheter_features():
        # With a catheter: its tip's offset behind the wire's tip over the robot's stroke.
        return np.zeros(0) if task.catheter is None else np.array([task.catheter_offset_m / robot.stroke_m])

    obs = {
        # The robot's pose as bounded features (insertion / stroke, sin and cos of the
        # rotation, which is never wrapped otherwise), then the wire's bending angles (rad).
        "joint_pos": observable.Generic(
            lambda physics: np.concatenate(
                [robot.pose_features(physics), physics.bind(wire_joints).qpos, catheter_features()]
            )
        ),
        # Robot rates as fractions of the drive's maximum speeds, then the wire's (rad/s).
        "joint_vel": observable.Generic(
            lambda physics: np.concatenate([robot.rate_features(physics), physics.bind(wire_joints).qvel])
        ),
        "wire_slack": observable.Generic(lambda physics: np.array([task.slack_m(physics)])),
        "drive_force": observable.Generic(lambda physics: np.array([robot.drive_force_n(physics)])),
        # What the robot's encoders measure: its pose and rates (joint_pos's and joint_vel's
        # first entries) and the catheter's offset; not the wire's shape.
        "robot_state": observable.Generic(
            lambda physics: np.concatenate(
                [robot.pose_features(physics), robot.rate_features(physics), catheter_features()]
            )
        ),
        # The registered roadmap around the tracked tip, in the tip's frame (tasks/roadmap.py),
        # as the task measured it at the end of the step.
        "roadmap": observable.Generic(roadmap.features),
        # The steps the tracked tip has stayed at the target's depth (the task's count), over DEPTH_CLOCK_STEPS.
        "target_depth_time": observable.Generic(
            lambda physics: np.array([min(task.steps_at_target_depth, DEPTH_CLOCK_STEPS) / DEPTH_CLOCK_STEPS])
        ),
        # The heading of a wrong branch entered before whose ostium the tracked tip is passing,
        # flagged, in the tip's frame (tasks/roadmap.py), as the task measured it.
        "wrong_branch_heading": observable.Generic(roadmap.wrong_branch_heading),
        # 1 once the expert's catheter rule has fired on the tracked tip this episode (the task's flag).
        "catheter_called": observable.Generic(lambda physics: np.array([float(task.catheter_called)])),
        # The catheter carriage's encoder: its speed over the last control step, over its maximum.
        "catheter_rate": observable.Generic(lambda physics: np.array([task.catheter_rate])),
        "pixels": observable.Generic(lambda physics: top_view.image(physics, settings.style)),
        # The registered roadmap overlaid on the fluoroscope's view: the lumen's silhouette
        # and the target, both off by the episode's registration error.
        "roadmap_overlay": observable.Generic(
            lambda physics: top_view.roadmap_overlay(
                physics, roadmap.registration_offset_m, task.target_position_m, task.success_radius_m
            )
        ),
        # The wire tracked in the image, and the roadmap projected into it (tasks/tracking2d.py),
        # as the task measured them at the end of the step.
        "tracking_2d": observable.Generic(image_tracker.tracked),
        "roadmap_2d": observable.Generic(image_tracker.roadmap),
        "tracking_2d_history": observable.Generic(image_tracker.history),
        # wrong_branch_heading and catheter_called kept from the image tracker's readings
        # instead of the 3-D tip's (the branch's heading in image coordinates).
        "wrong_branch_heading_2d": observable.Generic(image_tracker.wrong_branch_heading),
        "catheter_called_2d": observable.Generic(lambda physics: np.array([float(task.catheter_called_2d)])),
        "target_depth_time_2d": observable.Generic(
            lambda physics: np.array([min(task.steps_at_target_depth_2d, DEPTH_CLOCK_STEPS) / DEPTH_CLOCK_STEPS])
        ),
        # The C-arm's angles as it reports them: LAO (negative: RAO) and cranial (negative: caudal), radians.
        "carm_view": observable.Generic(lambda physics: np.radians(np.asarray(task.carm_view_deg, dtype=float))),
        "guidewire_mask": observable.Generic(top_view.mask),
        "tip_position": observable.MJCFFeature("xpos", guidewire.tip_site),
        # The step's wall force: the total averaged over its physics steps (at reset,
        # the total of the start state).
        "contact_force": observable.Generic(lambda physics: np.array([task.mean_wall_force_n], dtype=np.float64)),
    }
    for name, obs_item in obs.items():
        obs_item.enabled = name in settings.enabled or name in extra_observations
    if settings.noise_std > 0:
        obs["pixels"].corruptor = image_noise(settings.noise_std)
    if settings.style == "fluoro" and (settings.detector_dose_ngy > 0 or settings.blur_mm > 0):
        obs["pixels"].corruptor = detector_frame(top_view, settings)
    return obs, top_view, roadmap, image_tracker


def detector_frame(top_view: TopView, settings: ObservationSettings):
    """Observation corruptor: the clean fluoro image as one detector frame of
    `settings.detector_dose_ngy` and `settings.blur_mm` (`cathsim_dmc.sim.detector`), its
    quanta drawn from the environment's random state (a seeded episode stays reproducible).
    The pixel's size at the vessel is the episode's view's. With `noise_std` too, the
    Gaussian grey-level noise is added after."""
    grey = image_noise(settings.noise_std) if settings.noise_std > 0 else None

    def corrupt(value, random_state):
        pixel_m = top_view.drawn_pixel_size_m  # the image just drawn (the corruptor gets no physics)
        quanta = detector.background_quanta(settings.detector_dose_ngy, pixel_m)
        frame = detector.fluoroscopy_frame(
            value, random_state, quanta, 1e-3 * settings.blur_mm / pixel_m, 255.0 * raster.FLUORO_BACKGROUND
        )
        return frame if grey is None else grey(frame, random_state)

    return corrupt
