"""A user's class by name: 'package.module:Class' or 'path/to/file.py:Class'.

Importing a user's module runs the user's code: whatever it raises (SystemExit and
KeyboardInterrupt included) becomes one UserCodeError line naming the spec, the exception
and the file and line; a file module is registered in sys.modules before it runs (a
dataclass in it needs that) and its directory is put first on sys.path (its siblings
import, as `python file.py` lets them). Run it in a supervised worker (user_code.workers):
an import that calls os._exit or crashes then ends that worker, not the tool.
"""
import hashlib
import importlib
import importlib.util
import os
import sys

from ball_world.user_code.calls import call
from ball_world.user_code.describe import shown, UserCodeError


def split_spec(spec, option='--tracker'):
    """(module or file, class name) of a spec; UserCodeError for a malformed one."""
    if not isinstance(spec, str):
        raise UserCodeError(f'{option}: expected MODULE:CLASS or FILE.py:CLASS, got '
                            f'{shown(spec)}')
    module_name, _, class_name = spec.rpartition(':')
    if not module_name or not class_name.isidentifier():
        raise UserCodeError(f'{option} {shown(spec)}: expected MODULE:CLASS or '
                            'FILE.py:CLASS')
    return module_name, class_name


def _import_file(path):
    directory = os.path.dirname(os.path.abspath(path))
    if directory not in sys.path:
        sys.path.insert(0, directory)
    digest = hashlib.sha1(os.path.abspath(path).encode()).hexdigest()[:12]
    name = f'ball_world_user_{digest}'
    found = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(found)
    sys.modules[name] = module
    try:
        found.loader.exec_module(module)
    except BaseException:
        del sys.modules[name]
        raise
    return module


def load_class(spec, option='--tracker'):
    """The class (any callable) `spec` names; UserCodeError in one line when it cannot."""
    module_name, class_name = split_spec(spec, option)
    if module_name.endswith('.py'):
        if not os.path.isfile(module_name):
            raise UserCodeError(f'{option}: {module_name} is not a file')
        load = _import_file
    else:
        load = importlib.import_module
    try:
        module = call(f'{option}: importing {module_name}', load, module_name)
    except UserCodeError as error:
        raise UserCodeError(str(error).replace(' raised ', ' failed: ', 1)) from None
    found = getattr(module, class_name, None)
    if found is None or not callable(found):
        raise UserCodeError(f'{option}: {module_name} has no class {class_name}')
    return found
