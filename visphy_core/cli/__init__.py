"""The `visphy` command line: one module per subcommand group.
(See docs/architecture.md.)"""
