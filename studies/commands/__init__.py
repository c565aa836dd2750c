"""Subcommands of ``tvcid``; add a module here and to :data:`COMMAND_MODULES`."""
from . import features, fit, simulate, sindy, study

COMMAND_MODULES = (simulate, features, study, fit, sindy)
