"""Imports the verb modules of the command line so that they register (one module per verb)."""
