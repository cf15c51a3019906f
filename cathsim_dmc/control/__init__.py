"""What acts without learning: scripted policies, the privileged expert, keyboard teleoperation."""
