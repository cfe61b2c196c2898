"""Test helpers for visphy and its plugin authors: fake provider servers on loopback."""
