"""User code at arm's length: load a class by name, call it, check what it returns, and turn
every way it can end into one line and a non-zero exit, with no process left behind.

Trackers (ball_world_score --tracker) run here now; the robots' controllers will too. The
parts, each a module:

- `describe`: UserCodeError (a ValueError whose message is one line); one line for an
  exception (`describe_exception`: type, text, and the user's file:line nearest the
  failure), for a process's end (`describe_exit`: 'exited with status 3', 'killed by
  SIGSEGV'); `shown(value)`, a short rendering of any value that never fails.
- `loading.load_class(spec, option)`: the class of 'package.module:Class' or
  'path/to/file.py:Class'; an import that fails in any way is one UserCodeError line.
- `calls.call(what, function, *args)`: the call, any BaseException it raises as
  UserCodeError('{what} raised ...'); in a supervised worker under a deadline.
- `checks`: what user code returned, accepted or refused in one line naming who, when and
  the bad value: `track_rows` (a tracker's rows (id, x, y, ...)), `commands` (a
  controller's (N, 3) array of finite vx, vy, wz).
- `workers`: supervised worker processes that notice a worker's death (its sentinel) and
  enforce the deadline: `LocalPool` (an executor of jobs) and `Remote` (one object living
  in a worker of its own).

Executors. A benchmark maps jobs to workers through an executor, an object with

    executor.jobs                                    # how many run at once
    executor.map_unordered(function, arguments, labels)
        # yields (position, result) as jobs end, in any order; raises JobFailed (one line,
        # naming labels[position]) at the first job that fails or whose worker dies
    executor.close(abort=False)                      # no worker left waiting or running
    with executor: ...                               # close(abort=<an error left the block>)

`function` is importable by name and `function(argument)` is deterministic, with every
number its own: the caller puts results back in position order, so the report is the same
bit for bit whatever runs the jobs. `LocalPool(jobs, deadline_s, deadline_text)` is the
local one; `ray_pool.RayPool(address, jobs, most, deadline_s, deadline_text)` the same
jobs as Ray tasks on a cluster (`--ray ADDRESS|auto`; each task runs its job in a
LocalPool of one on its node, so failures are the same lines), chosen where the tool makes
its executor (tools.score_bench.executor); ray is imported only there.

Controllers (for the swarms' node; not wired yet). A controller is a class with act(obs)
-> commands. Run it as

    with Remote('my_pkg.ctl:Controller', '--controller', args=(), deadline_s=1.0,
                deadline_text='the controller deadline of 1 s') as controller:
        raw = controller.call('act', observation)    # numpy arrays travel as they are
        command = checks.commands(raw, count, 'my_pkg.ctl:Controller', 'at step 12')

Any failure (an exception, SystemExit, os._exit, a segfault, a call past the deadline) is a
JobFailed line, and the worker is gone; checks.commands refuses a shape other than
(count, 3) or a value that is not finite in one UserCodeError line.
"""
