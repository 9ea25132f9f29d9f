"""The layout's rules that code review alone keeps forgetting: ball_world/core has no ROS and
no I/O libraries, and no module imports itself through others: not in the core, not in the
package, the tools, the benchmarks or the test harness (docs/layout.md). A lazy import inside
a function counts: it only delays the circle."""
import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CORE = ROOT / 'ball_world' / 'core'
#: The code whose modules must import each other without a circle.
PACKAGES = ('ball_world', 'benchmarks', 'ball_world_testing')
#: Libraries of the shell, the files and the viewer: none belongs in the core.
OUTSIDE_CORE = ('rclpy', 'rosidl', 'mcap', 'rerun', 'geometry_msgs', 'std_msgs', 'ball_world.ros',
                'ball_world.recording', 'ball_world.msgs', 'ball_world.tools')


def imports(path, package=''):
    """Every module `path` imports, at the top or inside a function (a lazy import still
    makes a circle: it only delays it). package: the dotted package `path` is in, for
    relative imports."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            module = node.module or ''
            if node.level:
                parts = package.split('.')
                base = parts[:len(parts) - node.level + 1]
                module = '.'.join(base + ([module] if module else []))
            if module:
                found.add(module)
                found.update(f'{module}.{alias.name}' for alias in node.names)
    return found


def core_graph():
    modules = {path.stem: path for path in CORE.glob('*.py') if path.stem != '__init__'}
    graph = {}
    for name, path in modules.items():
        found = imports(path)  # each file parsed once (it was once per other module: 20 s)
        graph[name] = {other for other in modules if f'ball_world.core.{other}' in found}
    return graph


def test_core_imports_no_ros_and_no_file_formats():
    for path in CORE.glob('*.py'):
        bad = sorted(name for name in imports(path)
                     if any(name == lib or name.startswith(lib + '.') for lib in OUTSIDE_CORE))
        assert not bad, f'{path.name} imports {bad}'


def module_name(path):
    """The dotted name of a module file ('ball_world.tools' for its __init__.py)."""
    parts = list(path.relative_to(ROOT).with_suffix('').parts)
    return '.'.join(parts[:-1] if parts[-1] == '__init__' else parts)


def package_graph():
    """{module: the modules of PACKAGES it imports}, over every .py file of PACKAGES."""
    files = {module_name(path): path for package in PACKAGES
             for path in (ROOT / package).rglob('*.py')}
    graph = {}
    for name, path in files.items():
        package = name if path.name == '__init__.py' else name.rpartition('.')[0]
        graph[name] = {other for other in imports(path, package)
                       if other in files and other != name}
    return graph


def circle(graph):
    """One import circle of `graph` as a list of modules (first == last), or None."""
    done, path = set(), []

    def visit(name):
        if name in path:
            return path[path.index(name):] + [name]
        if name in done:
            return None
        path.append(name)
        for other in sorted(graph[name]):
            found = visit(other)
            if found:
                return found
        path.pop()
        done.add(name)
        return None

    for name in sorted(graph):
        found = visit(name)
        if found:
            return found
    return None


def test_the_circle_finder_finds_a_circle_and_only_a_circle():
    assert circle({'a': {'b'}, 'b': {'c'}, 'c': {'a'}, 'd': {'a'}}) == ['a', 'b', 'c', 'a']
    assert circle({'a': {'b', 'c'}, 'b': {'c'}, 'c': set()}) is None


def test_core_modules_import_each_other_without_a_circle():
    graph = core_graph()
    assert 'world' in graph['warm'] and 'exact' in graph['world']  # the graph is read
    found = circle(graph)
    assert found is None, f'import circle: {" -> ".join(found)}'


def test_no_module_of_the_package_tools_or_benchmarks_imports_itself_through_others():
    graph = package_graph()
    # the graph is read, lazy imports included, the tools' and the benchmarks' own
    assert 'ball_world.tools.repair_bag' in graph['ball_world.tools.repair']
    assert 'ball_world.tools.repair_mcap' in graph['ball_world.tools.repair_bag']
    assert 'benchmarks.scenes' in graph['benchmarks.agents']
    assert 'ball_world.recording.rerun_process' in graph['ball_world.recording.rerun_log']
    found = circle(graph)
    assert found is None, f'import circle: {" -> ".join(found)}'
