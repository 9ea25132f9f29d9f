"""ball_world_teleop's drive for agents: arrow keys become cmd_vel, as turtle_teleop_key does.

An agent (a ball that is a robot, core.agents) is driven, not pushed: each arrow key sends
one geometry_msgs/msg/Twist on `<name>/cmd_vel` in the agent's body frame, as
turtle_teleop_key sends one per key press to turtle1/cmd_vel: up forward, down backward,
left and right turn (counter-clockwise and clockwise). Held keys repeat, and the world's
agent.cmd_timeout stops the agent when they are let go. A ball is an agent when the world
subscribes to its cmd_vel: the graph says so, no list of agents is needed. The graph also
says which type it takes there: a world started with agent.cmd_vel_stamped gets
TwistStamped (command_type).
"""
from geometry_msgs.msg import Twist, TwistStamped
from rclpy.qos import QoSProfile, ReliabilityPolicy

#: Speed and turn rate a key commands at start, m/s and rad/s (turtle_teleop_key: 2 and 2);
#: + and - double and halve them with the impulse.
DEFAULT_SPEED = 1.0
DEFAULT_TURN = 2.0
#: Body-frame command of each arrow key: (forward, yaw rate) in units of speed and turn.
ARROW_COMMANDS = {'up': (1.0, 0.0), 'down': (-1.0, 0.0), 'left': (0.0, 1.0),
                  'right': (0.0, -1.0)}
_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)


STAMPED = 'geometry_msgs/msg/TwistStamped'


def command_type(node, topic):
    """TwistStamped when the graph shows only that type on `topic` (a world that takes it,
    agent.cmd_vel_stamped), else Twist."""
    name = node.resolve_topic_name(topic)
    types = dict(node.get_topic_names_and_types()).get(name, [])
    return TwistStamped if types and all(t == STAMPED for t in types) else Twist


def stamped(node, twist, frame_id=''):
    """The Twist as a TwistStamped, stamped with the node's clock now."""
    message = TwistStamped()
    message.header.stamp = node.get_clock().now().to_msg()
    message.header.frame_id = frame_id
    message.twist = twist
    return message


def twist_for(key, speed, turn):
    """The Twist an arrow key sends to an agent."""
    forward, rate = ARROW_COMMANDS[key]
    message = Twist()
    message.linear.x = forward * speed
    message.angular.z = rate * turn
    return message


class Drive:
    """cmd_vel publishers of the agents a Teleop node selected (see watch)."""

    def __init__(self, node):
        self.node = node
        self.speed = DEFAULT_SPEED
        self.turn = DEFAULT_TURN
        self._publishers = {}

    def is_agent(self, name):
        """Whether the world takes commands for `name` (it subscribes to its cmd_vel)."""
        return self.node.count_subscribers(f'{name}/cmd_vel') > 0

    def scale(self, factor):
        self.speed *= factor
        self.turn *= factor

    def watch(self, name):
        """Called while `name` is selected: an agent gets its publisher before the first key.

        A volatile publisher made at a key press would send its first Twist before the world
        has discovered it, and that key would be lost.
        """
        if name and name not in self._publishers and self.is_agent(name):
            self._publisher(name)

    def _publisher(self, name):
        publisher = self._publishers.get(name)
        if publisher is None:
            kind = command_type(self.node, f'{name}/cmd_vel')
            publisher = self.node.create_publisher(kind, f'{name}/cmd_vel', _QOS)
            self._publishers[name] = publisher
        return publisher

    def ready(self, name):
        """Whether a command to `name` now reaches a subscriber (the world has matched us)."""
        publisher = self._publishers.get(name)
        return publisher is not None and publisher.get_subscription_count() > 0

    def send(self, name, key):
        """Send the key's command to agent `name`; returns the status line."""
        publisher = self._publisher(name)
        if publisher.get_subscription_count() == 0:
            return f'not sent: nobody subscribes to {publisher.topic_name} yet'
        message = twist_for(key, self.speed, self.turn)
        publisher.publish(stamped(self.node, message) if publisher.msg_type is TwistStamped
                          else message)
        return (f'drive: {name} forward {message.linear.x:+.3g} m/s, turn '
                f'{message.angular.z:+.3g} rad/s')
