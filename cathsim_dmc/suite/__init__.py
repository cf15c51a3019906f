"""The Gymnasium adapter on the task suite (cathsim_dmc.tasks)."""
