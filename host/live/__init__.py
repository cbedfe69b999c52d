"""What talks to running DPUs: spawning them, the config on the wire, control, listening, a run."""
