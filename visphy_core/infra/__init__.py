"""Infrastructure with no knowledge of models or metrics: video and PNG I/O, the content-addressed
cache, safe file writes, memory trimming, vendored JavaScript assets.
(See docs/architecture.md.)"""
