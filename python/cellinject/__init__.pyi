from . import design as design
from . import dic as dic
from . import fea as fea
from . import flexure as flexure
from . import hysteresis as hysteresis
from . import model as model
from . import rig as rig
from . import vision as vision
from . import runs as runs
from . import twin as twin
from ._errors import Error as Error
from ._errors import InputError as InputError
from ._errors import NotConverged as NotConverged

__version__: str
