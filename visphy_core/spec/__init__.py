"""Scene specifications: the 2D/3D spec schemas, the spec a reply states, the replay payloads, the
spec track (re-simulating a stated spec) and interventions.
(See docs/architecture.md.)"""
