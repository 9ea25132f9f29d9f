"""The layout's rules that code review alone keeps forgetting: ball_world/core has no ROS and
no I/O libraries, and its modules import each other without a circle (docs/layout.md)."""
import ast
from pathlib import Path

CORE = Path(__file__).resolve().parents[1] / 'ball_world' / 'core'
#: Libraries of the shell, the files and the viewer: none belongs in the core.
OUTSIDE_CORE = ('rclpy', 'rosidl', 'mcap', 'rerun', 'geometry_msgs', 'std_msgs', 'ball_world.ros',
                'ball_world.recording', 'ball_world.msgs', 'ball_world.tools')


def imports(path):
    """Every module `path` imports, at the top or inside a function (a lazy import still
    makes a circle: it only delays it)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module:
            found.add(node.module)
            found.update(f'{node.module}.{alias.name}' for alias in node.names)
    return found


def core_graph():
    modules = {path.stem: path for path in CORE.glob('*.py') if path.stem != '__init__'}
    return {name: {other for other in modules if f'ball_world.core.{other}' in imports(path)}
            for name, path in modules.items()}


def test_core_imports_no_ros_and_no_file_formats():
    for path in CORE.glob('*.py'):
        bad = sorted(name for name in imports(path)
                     if any(name == lib or name.startswith(lib + '.') for lib in OUTSIDE_CORE))
        assert not bad, f'{path.name} imports {bad}'


def test_core_modules_import_each_other_without_a_circle():
    graph = core_graph()
    assert 'world' in graph['warm'] and 'exact' in graph['world']  # the graph is read
    done, path = set(), []

    def visit(name):
        assert name not in path, f'import circle: {" -> ".join(path[path.index(name):])} -> {name}'
        if name in done:
            return
        path.append(name)
        for other in sorted(graph[name]):
            visit(other)
        path.pop()
        done.add(name)

    for name in sorted(graph):
        visit(name)
