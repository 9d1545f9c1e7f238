# The notebook API (__init__.py's docstring) and the subpackages, for type checkers, editors and the API pages
# (`name as name`: a stub's re-export, PEP 484). At run time lazy_loader.attach_stub (in __init__.py) reads the
# relative imports here and imports each name, and each subpackage (`aj.experiment`), when first used; make, make_env
# and list_tasks __init__.py imports itself (lazy_loader takes no alias, `make_env = make`, from a stub).
from . import analysis as analysis
from . import cli as cli
from . import envs as envs
from . import experiment as experiment
from . import nets as nets
from . import ppo as ppo
from . import vision as vision
from .envs.registry import list_tasks as list_tasks
from .envs.registry import make as make
from .experiment import list_configs as list_configs
from .experiment import load_agent as load_agent
from .experiment import load_config as load_config
from .experiment import resume as resume
from .experiment import train as train
from .experiment.evaluation import evaluate as evaluate
from .experiment.export import export_policy as export_policy
from .experiment.export import load_policy as load_policy
from .experiment.video import render_frames as render_frames

make_env = make
