"""The command-line tools: their typed config schemas and the Hydra apps (cli/)."""
