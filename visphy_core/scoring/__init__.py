"""Scoring one scene: the scoring protocols (pairings), alignment, the paper protocol, variance
normalisation, the ground-truth anchors, the headline, metric weights.
(See docs/architecture.md.)"""
