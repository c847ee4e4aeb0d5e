"""The command line (`asset-preview`, `asset-bake`): settings of the process it runs in."""
import gc
import os

# A cold command creates some 80,000 objects while importing (modules, classes, pydantic
# schemas, pxr's wrappers) that live as long as the process; at the default threshold of
# 700 allocations the collector walks them over a hundred times, a seventh of the imports'
# CPU time. Collecting every 20,000 still bounds what cyclic garbage can pile up.
gc.set_threshold(20_000, 10, 10)

# pydantic looks for plugins on its first model by reading the entry points of every
# installed distribution (importlib.metadata: a twentieth of a cold render's CPU); this
# project uses none. An explicit PYDANTIC_DISABLE_PLUGINS (e.g. empty: load them all) wins.
os.environ.setdefault("PYDANTIC_DISABLE_PLUGINS", "__all__")
