"""visphy: probe physical understanding of multimodal LLMs by making them write simulators."""

__version__ = "0.1.0"
