"""Ground-side attitude estimators. They take SI sensor samples and know nothing of MAVLink."""
