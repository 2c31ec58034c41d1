"""Subcommands of the ``meshadv`` command line, one module each (registered in :mod:`meshadv.cli`)."""
