"""Running a scenario: the launcher (physics, root channel, supervised processes) and port allocation."""
