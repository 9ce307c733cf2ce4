"""The orchestrator's own ROS node: it hears every step topic for the recorder, resets the simulator, and guards
the run's topics and services against intruders (:class:`aril_ros_nodes.common.PublisherGuard`). rclpy is imported
only when a client is made, so ``run_graph.py --help`` and a refused argument do not wait for it."""
from __future__ import annotations

import time

from aril_ros import protocol as P
from aril_ros.runlog import RunLogError, StepFault, StepRecorder
from aril_ros_nodes.launcher import GraphError


class GraphClient:
    """The orchestrator's own ROS node: raw subscriptions for the recorder and the reset client, and the guards of
    every step topic and service (:class:`aril_ros_nodes.common.PublisherGuard`): once :meth:`admit` has checked
    who is connected, a publisher or service client that joins later stops the run, named."""

    NAME = "orchestrator"

    def __init__(self, recorder: StepRecorder, camera: bool = False):
        import rclpy
        from rcl_interfaces.srv import SetParametersAtomically
        from rclpy.experimental import EventsExecutor
        from rclpy.signals import SignalHandlerOptions
        from rosgraph_msgs.msg import Clock
        from sensor_msgs.msg import JointState
        from std_msgs.msg import String

        from aril_ros_nodes.common import READY_QOS, STEP_QOS, PublisherGuard, guarded_subscription

        self._rclpy = rclpy
        # no rclpy signal handlers: Ctrl-C must reach the orchestrator's own handler
        rclpy.init(args=[], signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node(self.NAME)
        classes = {"sensor_msgs/msg/JointState": JointState, "rosgraph_msgs/msg/Clock": Clock}
        self.guards = {
            topic: guarded_subscription(self.node, classes[msg_type], topic,
                                        lambda raw, topic=topic: self.receive(topic, recorder.on_message, topic, raw),
                                        STEP_QOS, raw=True)
            for topic, msg_type in P.MESSAGE_TYPES.items() if topic in recorder.topics}
        if camera:
            from sensor_msgs.msg import CompressedImage

            self.guards[P.CAMERA] = guarded_subscription(self.node, CompressedImage, P.CAMERA,
                                                         lambda raw: self.receive(P.CAMERA, recorder.on_frame, raw),
                                                         STEP_QOS, raw=True)
        self.service_guards = [PublisherGuard(self.node, name, service=True)
                               for name in (P.RESET_SERVICE, P.SET_STATE_SERVICE)]
        # what stops the run, raised by spin(): raised inside a callback it would also be logged by the executor
        self.fault: GraphError | RunLogError | None = None
        self.ready: set[str] = set()
        self.node.create_subscription(String, P.READY, lambda msg: self.ready.add(msg.data), READY_QOS)
        self.reset_client = self.node.create_client(SetParametersAtomically, P.RESET_SERVICE)
        self._request_type = SetParametersAtomically.Request
        self.executor = EventsExecutor()
        self.executor.add_node(self.node)
        self.next_look = 0.0  # when spin() next checks every guard

    def spin(self, timeout: float) -> None:
        """Handle one event (a message, a matched event, an answer), or wait ``timeout`` seconds for one; every
        :data:`~aril_ros_nodes.common.GRAPH_POLL` seconds, look for an intruder that has not sent yet (a message is
        checked as it arrives: looking after each of the 8 of a step would double the orchestrator's work)."""
        from aril_ros_nodes.common import GRAPH_POLL, IntruderError

        self.executor.spin_once(timeout_sec=timeout)
        if time.monotonic() >= self.next_look:
            self.next_look = time.monotonic() + GRAPH_POLL
            try:
                for guard in [*self.guards.values(), *self.service_guards]:
                    guard.check()
            except IntruderError as err:
                self.fault = self.fault or GraphError(str(err))
        if self.fault is not None:
            raise self.fault

    def receive(self, topic: str, handler, *args) -> None:
        """A message on ``topic`` to ``handler``, once its publisher is known to be admitted; a fault in it names
        the admitted publisher(s), the only ones it can have come from. After a fault nothing more is taken."""
        from aril_ros_nodes.common import IntruderError

        if self.fault is not None:
            return
        guard = self.guards[topic]
        try:
            guard.check()
            handler(*args)
        except IntruderError as err:
            self.fault = GraphError(str(err))
        except StepFault as err:
            self.fault = GraphError(f"{err}, from {guard.describe()}")
        except RunLogError as err:  # the log could not be written (a full disk): raised from spin, not in rclpy's callback
            self.fault = err

    def admit(self, own_nodes: set[str], external_policy: bool) -> None:
        """Admit the publishers and service peers connected now, if each is one of ``own_nodes`` (the names of
        the nodes this run started: unique in the domain, so no other node can pass for one) or, with an
        external policy, the one node publishing on action that this run did not start."""
        from aril_ros_nodes.common import endpoint_text

        guards = [*self.guards.values(), *self.service_guards]
        admitted = {guard: guard.admit() for guard in guards}  # this waits until the graph knows their node names
        names = [name for name, _ in self.node.get_node_names_and_namespaces()]
        impostors = sorted({name for name in names if name in own_nodes and names.count(name) > 1})
        if impostors:
            endpoints = [f"{endpoint_text(info)} on {guard.what}" for guard, infos in admitted.items()
                         for info in infos if info.node_name in impostors]
            raise GraphError(f"more than one node named {', '.join(impostors)} in the run's domain: another process "
                             "passes for one of this run's nodes (" + ("; ".join(endpoints) or "no step endpoints")
                             + ")")
        for guard, infos in admitted.items():
            strangers = [info for info in infos if info.node_name not in own_nodes]
            if external_policy and guard is self.guards[P.ACTION] and len(strangers) == 1:
                continue  # the external policy node the user started
            if strangers:
                raise GraphError(f"intruder on {guard.what}: " + ", ".join(endpoint_text(i) for i in strangers)
                                 + ", not one of this run's nodes" + (" (an external policy publishes on action "
                                                                      "alone)" if external_policy else ""))

    def hears_probes(self) -> bool:
        """Whether the recorder knows the attacker's probe client as a publisher on observation. The attacker's
        readiness says only that the client matched the recorder (each side discovers the other on its own), and
        a publisher the recorder meets after admission is an intruder."""
        return any(info.node_name == P.PROBE_CLIENT for info in self.guards[P.OBSERVATION].publishers())

    def unfed_topics(self) -> list[str]:
        """Step topics whose publisher is not yet matched with the recorder."""
        return [topic for topic, guard in self.guards.items() if guard.subscription.get_publisher_count() < 1]

    def external_endpoints(self, own_nodes: set[str]) -> dict[str, list[str]]:
        """The nodes not in ``own_nodes`` that show a subscription on observation, and a publisher on action."""
        observation, action = (self.node.resolve_topic_name(t) for t in (P.OBSERVATION, P.ACTION))
        return {f"a subscriber on {observation}": [info.node_name for info in
                                                   self.node.get_subscriptions_info_by_topic(observation)
                                                   if info.node_name not in own_nodes],
                f"a publisher on {action}": [info.node_name for info in self.node.get_publishers_info_by_topic(action)
                                             if info.node_name not in own_nodes]}

    def best_effort_policy(self) -> str | None:
        """Why a node's publisher on action is in the graph but matched by none of the run's subscriptions: it is
        best effort, which no reliable subscription matches."""
        from rclpy.qos import ReliabilityPolicy

        action = self.node.resolve_topic_name(P.ACTION)
        best_effort = [info.node_name for info in self.node.get_publishers_info_by_topic(action)
                       if info.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT]
        return (f"node '{best_effort[0]}' publishes on {action} best effort, which no reliable subscription matches: "
                "step topics are reliable" if best_effort else None)

    def reset(self, seed: int, episode: int, check, timeout: float) -> None:
        from aril_ros_nodes.common import param_msg

        request = self._request_type()
        request.parameters = [param_msg("seed", seed), param_msg("episode", episode)]
        future = self.reset_client.call_async(request)
        deadline = time.monotonic() + timeout
        while not future.done():
            self.spin(0.05)
            check()
            if time.monotonic() > deadline:
                raise GraphError(f"the simulator did not answer {P.RESET_SERVICE} within {timeout:.0f} s")
        result = future.result().result
        if not result.successful:
            raise GraphError(f"the simulator refused to reset: {result.reason}")

    def close(self) -> None:
        from rclpy.utilities import get_default_context

        self.executor.shutdown()
        self.node.destroy_node()
        self._rclpy.try_shutdown()
        get_default_context().destroy()  # the DDS participant leaves now, not at the process's teardown
