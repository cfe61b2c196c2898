"""The run-directory format: its layout, its row type and columns, discovery and loading of runs,
the summary and the one atomic writer.
(See docs/architecture.md.)"""
