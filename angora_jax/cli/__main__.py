"""`python -m angora_jax.cli`: the `angora-jax` command."""

import sys

from angora_jax.cli import main

sys.exit(main())
