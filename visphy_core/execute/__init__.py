"""Executing runs: the run, the per-scene pipeline, the scheduler, the console, dataset selection
and shards, re-scoring, merging, rendering one program.
(See docs/architecture.md.)"""
