"""Test harnesses shipped with the package: stand-ins for hardware that tests (and users, from the CLI) run against.

Nothing in the plugin's own code imports from here.
"""
