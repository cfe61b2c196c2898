"""Checking configuration: run config validation and the config of a re-score.
(See docs/architecture.md.)"""
