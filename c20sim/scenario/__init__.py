"""Scenarios: TOML timelines in virtual time (timeline), many at once (suite), and the formats' schemas."""
