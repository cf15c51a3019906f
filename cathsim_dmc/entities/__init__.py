"""Reusable composer entities: attach them in your own composer tasks."""

from cathsim_dmc.core.shipped import available_aortas
from cathsim_dmc.entities.aorta import Aorta
from cathsim_dmc.entities.follower import FollowerRobot
from cathsim_dmc.entities.guidewire import Guidewire
from cathsim_dmc.entities.target import TargetMarker

__all__ = ["Aorta", "FollowerRobot", "Guidewire", "TargetMarker", "available_aortas"]
