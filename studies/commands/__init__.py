"""Subcommands of ``tvcid``; add a module here and to :data:`COMMAND_MODULES`."""
from . import df, discover, features, fit, simulate, sindy, spectrum, study

COMMAND_MODULES = (simulate, features, study, fit, sindy, discover, df, spectrum)
