"""Wire-wall contact force distribution: per physics step and per control step.

    python experiments/force_distribution.py --aortas type1 --episodes 100 --adversarial-steps 5000

For each aorta it runs `--episodes` scripted-expert episodes per target (seeds 0, 1, ...)
and `--adversarial-steps` control steps of adversarial actions (on the BCA task, reset
whenever an episode ends), and records the total wire-wall contact force (the sum of
the contact force magnitudes on the vessel wall; the guide channel and seal are not
tissue) of every physics step, at the point of the step where contacts and constraint
forces belong to the same state (`ConstraintSensingPhysics.after_constraint_solve`).

It prints a Markdown table of percentiles over

  * physics steps: the total force of each physics step;
  * control steps, step mean: the average of a control step's physics steps
    (`info["mean_contact_force_n"]`);
  * control steps, end of step: the force in the state after the control step
    (`info["contact_force_n"]`);

then the largest physics-step forces with where they happened (source, aorta, seed or
adversarial step, control step, physics step within it, contacts and deepest penetration),
so that a spike can be replayed. `--guidewire key=value` (and `--robot`, `--task`) override
entity parameters (values parsed as JSON: `--guidewire mass_scale=625`) to compare
physics settings on the same seeds; `--json` writes everything for later comparison.

Adversarial actions are `policy=adversarial` (`cathsim_dmc.control.policies.AdversarialPolicy`):
bursts of 5-40 control steps, each one of: uniform random; bang-bang (each axis -1 or +1,
held 1-5 steps); insert-and-rotate at full stroke ([1, +-1]); rapid reversals (insertion
flips sign every step, rotation full).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import dataclass, field

import numpy as np

from cathsim_dmc.control.policies import AdversarialPolicy, make_policy
from cathsim_dmc.sim import physics as cs_physics
from cathsim_dmc.suite.gym import CathSimEnv

PERCENTILES = (50, 99, 99.9, 100)


@dataclass
class Samples:
    """Force samples of one source (expert on one target, or adversarial) on one aorta."""

    source: str
    aorta: str
    physics_n: list = field(default_factory=list)  # one per physics step
    mean_n: list = field(default_factory=list)  # one per control step
    end_n: list = field(default_factory=list)  # one per control step
    events: list = field(default_factory=list)  # the largest physics-step forces, with where
    depth_m: list = field(default_factory=list)  # deepest wall contact of each physics step
    episodes: int = 0
    successes: int = 0
    escapes: int = 0  # steps that ended an episode with the wire outside the anatomy
    divergences: int = 0

    def add_event(self, event: dict, keep: int) -> None:
        self.events.append(event)
        if len(self.events) > 4 * keep:
            self.events.sort(key=lambda e: -e["force_n"])
            del self.events[keep:]


class PhysicsStepProbe:
    """Records each physics step's total wall force (and its contacts) of a CathSimEnv,
    calling the task's own per-physics-step callback as well."""

    def __init__(self, env: CathSimEnv):
        self.env = env
        self.forces, self.contacts, self.depths = [], [], []

    def attach(self) -> None:
        """Call after each reset: the task installs its callback there."""
        physics, task = self.env.physics, self.env.task
        task_callback = physics.after_constraint_solve
        wire = np.zeros(physics.model.ngeom, dtype=bool)
        wire[physics.bind(task.guidewire.geoms).element_id] = True
        vessel = np.zeros(physics.model.ngeom, dtype=bool)
        vessel[task.aorta.wall_geom_ids(physics)] = True

        def probe(p):
            if task_callback is not None:
                task_callback(p)
            data = p.data.ptr
            if data.ncon:
                _, _, keep = cs_physics._wire_contact_rows(data, wire, vessel)
                count = int(keep.sum())
                # Past the constraint surface: a wall with a contact margin starts acting
                # that far from its pieces.
                inside = data.contact.includemargin[: data.ncon][keep] - data.contact.dist[: data.ncon][keep]
                depth = float(inside.max()) if count else 0.0
            else:
                count, depth = 0, 0.0
            self.forces.append(cs_physics.total_contact_force_n(p, wire, vessel))
            self.contacts.append(count)
            self.depths.append(depth)

        physics.after_constraint_solve = probe

    def take(self):
        """(forces, contact counts, depths) recorded since the last call."""
        out = np.array(self.forces), np.array(self.contacts), np.array(self.depths)
        self.forces, self.contacts, self.depths = [], [], []
        return out


def _record_step(samples: Samples, probe: PhysicsStepProbe, info: dict, where: dict, keep: int) -> None:
    forces, counts, depths = probe.take()
    samples.physics_n.extend(forces.tolist())
    samples.mean_n.append(info["mean_contact_force_n"])
    samples.end_n.append(info["contact_force_n"])
    samples.depth_m.extend(depths.tolist())
    samples.escapes += int(info["escaped"])
    samples.divergences += int(info["diverged"])
    if len(forces):
        i = int(forces.argmax())
        samples.add_event(
            dict(
                where,
                substep=i + 1,
                force_n=float(forces[i]),
                contacts=int(counts[i]),
                depth_mm=1e3 * float(depths[i]),
                step_mean_n=float(info["mean_contact_force_n"]),
            ),
            keep,
        )


def run_expert(aorta: str, target: str, episodes: int, env_kwargs: dict, keep: int, seed: int = 0) -> Samples:
    env = CathSimEnv(task=target, aorta=aorta, obs="internal", **env_kwargs)
    samples = Samples(f"expert {target}", aorta)
    probe = PhysicsStepProbe(env)
    for episode in range(seed, seed + episodes):
        observation, _ = env.reset(seed=episode)
        probe.attach()
        policy = make_policy("expert", seed=episode)
        done = False
        while not done:
            observation, _, terminated, truncated, info = env.step(policy(observation, env))
            _record_step(samples, probe, info, dict(seed=episode, step=info["step"]), keep)
            done = terminated or truncated
        samples.episodes += 1
        samples.successes += int(terminated)
    env.close()
    return samples


def run_adversarial(
    aorta: str, steps: int, env_kwargs: dict, keep: int, seed: int = 0, report_every: int = 0, report=None
) -> Samples:
    """`steps` adversarial control steps; every `report_every` steps `report(samples)` sees
    the samples so far (a long sweep keeps its partial results)."""
    # Long episodes, so that bursts reach the end of the stroke and buckle the wire.
    kwargs = dict(env_kwargs)
    kwargs.setdefault("max_steps", 1000)
    env = CathSimEnv(task="bca", aorta=aorta, obs="internal", **kwargs)
    samples = Samples("adversarial", aorta)
    probe = PhysicsStepProbe(env)
    env.reset(seed=seed)
    probe.attach()
    samples.episodes = 1
    policy = AdversarialPolicy(seed)
    for k in range(1, steps + 1):
        _, _, terminated, truncated, info = env.step(policy())
        _record_step(
            samples, probe, info, dict(seed=seed, adversarial_step=k, mode=policy.mode, step=info["step"]), keep
        )
        if terminated or truncated:
            env.reset()
            probe.attach()
            samples.episodes += 1
        if report is not None and report_every and k % report_every == 0:
            report(samples)
    env.close()
    return samples


def percentiles(values) -> list:
    values = np.asarray(values, dtype=float)
    return np.percentile(values, PERCENTILES).tolist() if len(values) else [float("nan")] * len(PERCENTILES)


def summary(samples: Samples) -> dict:
    return dict(
        source=samples.source,
        aorta=samples.aorta,
        episodes=samples.episodes,
        successes=samples.successes,
        physics_steps=len(samples.physics_n),
        control_steps=len(samples.mean_n),
        physics=percentiles(samples.physics_n),
        step_mean=percentiles(samples.mean_n),
        end_of_step=percentiles(samples.end_n),
        end_of_step_zero_pct=100.0 * float(np.mean(np.asarray(samples.end_n) == 0.0)) if samples.end_n else None,
        end_vs_mean_corr=(
            float(np.corrcoef(samples.end_n, samples.mean_n)[0, 1])
            if len(samples.end_n) > 2 and np.std(samples.end_n) > 0 and np.std(samples.mean_n) > 0
            else None
        ),
        depth_mm=[1e3 * v for v in percentiles(samples.depth_m)],
        escapes=samples.escapes,
        divergences=samples.divergences,
        events=sorted(samples.events, key=lambda e: -e["force_n"]),
    )


def _row(cells) -> str:
    return "| " + " | ".join(cells) + " |"


def markdown(summaries: list, top: int) -> str:
    p = "/".join("max" if q == 100 else f"p{q:g}" for q in PERCENTILES)
    lines = [
        _row(
            [
                "Aorta",
                "Source",
                "Episodes (success)",
                "Physics steps",
                f"Physics step {p} (N)",
                f"Step mean {p} (N)",
                f"End of step {p} (N)",
                "End of step = 0",
                "corr(end, mean)",
                f"Deepest contact {p} (mm)",
                "Escaped / diverged",
            ]
        ),
        "|" + "---|" * 11,
    ]
    fmt = lambda values: " / ".join(f"{v:.2f}" for v in values)  # noqa: E731
    for s in summaries:
        episodes = f"{s['episodes']}" + (f" ({s['successes']})" if s["source"].startswith("expert") else "")
        corr = "n/a" if s["end_vs_mean_corr"] is None else f"{s['end_vs_mean_corr']:.2f}"
        lines.append(
            _row(
                [
                    s["aorta"],
                    s["source"],
                    episodes,
                    f"{s['physics_steps']:,}",
                    fmt(s["physics"]),
                    fmt(s["step_mean"]),
                    fmt(s["end_of_step"]),
                    f"{s['end_of_step_zero_pct']:.0f}%",
                    corr,
                    " / ".join(f"{v:.3f}" for v in s["depth_mm"]),
                    f"{s['escapes']} / {s['divergences']}",
                ]
            )
        )
    events = sorted(
        (dict(e, source=s["source"], aorta=s["aorta"]) for s in summaries for e in s["events"]),
        key=lambda e: -e["force_n"],
    )[:top]
    if events:
        lines += [
            "",
            "Largest physics-step forces:",
            "",
            _row(
                [
                    "Force (N)",
                    "Aorta",
                    "Source",
                    "Where",
                    "Physics step",
                    "Contacts",
                    "Deepest (mm)",
                    "Its step mean (N)",
                ]
            ),
            "|" + "---|" * 8,
        ]
        for e in events:
            where = (
                f"adversarial step {e['adversarial_step']} ({e['mode']})"
                if "adversarial_step" in e
                else f"seed {e['seed']}, step {e['step']}"
            )
            lines.append(
                _row(
                    [
                        f"{e['force_n']:.2f}",
                        e["aorta"],
                        e["source"],
                        where,
                        str(e["substep"]),
                        str(e["contacts"]),
                        f"{e['depth_mm']:.3f}",
                        f"{e['step_mean_n']:.2f}",
                    ]
                )
            )
    return "\n".join(lines) + "\n"


def _overrides(pairs) -> dict:
    out = {}
    for pair in pairs or ():
        key, sep, value = pair.partition("=")
        if not sep:
            raise SystemExit(f"override {pair!r} is not key=value")
        try:
            out[key] = json.loads(value)
        except json.JSONDecodeError:
            out[key] = value
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--aortas", nargs="+", default=["type1"])
    parser.add_argument("--targets", nargs="+", default=["bca", "lcca"])
    parser.add_argument("--episodes", type=int, default=100, help="expert episodes per target and aorta")
    parser.add_argument("--adversarial-steps", type=int, default=5000, help="adversarial control steps per aorta")
    parser.add_argument("--seed", type=int, default=0, help="first expert seed; the adversarial run's seed")
    parser.add_argument("--guidewire", nargs="*", default=[], metavar="KEY=VALUE", help="Guidewire overrides")
    parser.add_argument("--robot", nargs="*", default=[], metavar="KEY=VALUE", help="FollowerRobot overrides")
    parser.add_argument("--task", nargs="*", default=[], metavar="KEY=VALUE", help="Navigate overrides")
    parser.add_argument("--top", type=int, default=10, help="largest physics-step forces listed")
    parser.add_argument("--json", help="write the summaries (with the largest events) to this file")
    parser.add_argument(
        "--report-every",
        type=int,
        default=10_000,
        help="adversarial steps between progress lines (and, with --json, <json>.partial files)",
    )
    args = parser.parse_args(argv)
    env_kwargs = _overrides(args.task)
    if args.guidewire:
        env_kwargs["guidewire"] = _overrides(args.guidewire)
    if args.robot:
        env_kwargs["robot"] = _overrides(args.robot)

    summaries, started = [], time.time()

    def report_partial(samples):
        partial = summary(samples)
        print(
            f"# {partial['aorta']} adversarial: {partial['control_steps']} steps so far, physics max "
            f"{partial['physics'][-1]:.2f} N, escapes {partial['escapes']} ({time.time() - started:.0f} s)",
            file=sys.stderr,
            flush=True,
        )
        if args.json:
            with open(args.json + ".partial", "w") as f:
                json.dump(dict(args=vars(args), summaries=[*summaries, partial]), f, indent=1)

    for aorta in args.aortas:
        runs = [
            lambda t=t: run_expert(aorta, t, args.episodes, env_kwargs, args.top, args.seed)
            for t in args.targets
            if args.episodes > 0
        ]
        if args.adversarial_steps > 0:
            runs.append(
                lambda: run_adversarial(
                    aorta, args.adversarial_steps, env_kwargs, args.top, args.seed, args.report_every, report_partial
                )
            )
        for run in runs:
            summaries.append(summary(run()))
            s = summaries[-1]
            print(
                f"# {s['aorta']} {s['source']}: {s['control_steps']} control steps, physics max "
                f"{s['physics'][-1]:.2f} N ({time.time() - started:.0f} s)",
                file=sys.stderr,
                flush=True,
            )
    print(markdown(summaries, args.top), end="")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(dict(args=vars(args), summaries=summaries), f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
