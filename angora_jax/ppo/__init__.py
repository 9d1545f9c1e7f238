"""PPO with recurrent truncated BPTT, compiled as one program per training cycle.

`train(config)` runs a whole experiment; `make_cycle(env, network, config)` gives the compiled pieces.
"""

import lazy_loader

# The names this package gives (its __all__), each imported when first used: __init__.pyi lists them, where type
# checkers, editors and the API pages read them.
__getattr__, __dir__, __all__ = lazy_loader.attach_stub(__name__, __file__)
