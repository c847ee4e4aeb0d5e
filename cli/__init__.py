"""The command line (`asset-preview`, `asset-bake`)."""
import os

# pydantic looks for plugins on its first model by reading the entry points of every
# installed distribution (importlib.metadata: a tenth of a cold render's own CPU time); this
# project uses none. An explicit PYDANTIC_DISABLE_PLUGINS (e.g. empty: load them all) wins.
os.environ.setdefault("PYDANTIC_DISABLE_PLUGINS", "__all__")
