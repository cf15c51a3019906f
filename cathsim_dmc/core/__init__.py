"""Names, file locations and checks that every layer shares; no simulator, no learning library."""
