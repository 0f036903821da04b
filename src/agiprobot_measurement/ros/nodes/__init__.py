"""Node classes: each file in nodes/ imports one of these and runs it."""
