"""Subcommands of ``tvcid``; add a module here and to :data:`COMMAND_MODULES`."""
from . import design, df, discover, features, fit, predict, simulate, sindy, spectrum

COMMAND_MODULES = (simulate, features, fit, sindy, discover, df, spectrum, predict, design)
