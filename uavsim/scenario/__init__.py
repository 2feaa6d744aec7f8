"""Visual-servoing scenarios (issue 7)."""
