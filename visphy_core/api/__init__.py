"""What plugins import: the hook specifications, the plugin registry and the contracts a plugin
implements (engine, model, metric, judge, physics, dataset, scene, errors, settings, config
schemas).
(See docs/architecture.md.)"""
