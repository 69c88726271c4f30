from .load import *  # noqa: F401,F403
from .load import read_toml, _toml_value, AUTO  # noqa: F401
