"""What the ground station knows of and asks from the vehicle: identity and mode, streams."""
