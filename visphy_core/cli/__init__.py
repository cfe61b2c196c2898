"""The `visphy` command line: one module per subcommand group."""
