"""Pure computation on a loaded system: frames, schedules, the prediction, an allocation."""
