"""The main of a tool that is one ROS node (ball_world_wander, ball_world_navigate): its
command line, its node's life and every way it ends.

Why one place: each such tool must refuse a bad command line in one line, print its help,
make its node under rcl_init's watchdog (one line when DDS never lets it join the graph),
spin it until Ctrl-C or SIGTERM (ros.stopping: a clean exit 0), turn the errors it names
into one line and exit 2, and destroy the node and shut rclpy down however it ends.
"""
import sys


def run(prog, help_text, make_node, errors=(), argv=None):
    """Run the node make_node() returns until the process is stopped; the exit status.

    help_text: what --help prints; errors: exception types whose text is the one line of a
    refusal (exit 2). A node with a start() method has it called once it is made, outside
    the watchdog's time (a policy's torch import is no stuck node).
    """
    import rclpy
    from rclpy.utilities import remove_ros_args

    from ball_world.ros.rcl_init import creating_node
    from ball_world.ros.stopping import stopped_by_signal
    argv = sys.argv if argv is None else argv
    try:
        own = remove_ros_args(argv)[1:]
    except Exception as error:  # noqa: B902 - rcl reports bad arguments as generic errors
        return fail(prog, f'bad ROS arguments: {error}')
    if own in (['-h'], ['--help']):
        print(help_text)
        return 0
    if own:
        return fail(prog, f"unrecognized arguments: {' '.join(own)} (see --help)")
    node = None
    try:
        with stopped_by_signal():
            rclpy.init(args=argv)
            with creating_node(prog):
                node = make_node()
            if hasattr(node, 'start'):
                node.start()
            while rclpy.ok():
                rclpy.spin_once(node, timeout_sec=0.1)
    except tuple(errors) as error:
        return fail(prog, error)
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0


def fail(prog, message):
    """Say why in one line on stderr; the exit status of a refusal."""
    print(f'{prog}: {message}', file=sys.stderr)
    return 2
