"""Which node ``laser_odom_replay --live`` drives, and whose parameters a replay reads.

Shared by the offline replay (:mod:`laser_odom.tools.replay`, which reads the params
file for that node's name) and the live one (:mod:`laser_odom.tools.replay_live`, which
finds that node on the graph), so that neither imports the other.
"""

from __future__ import annotations

import argparse

from laser_odom.ros.graph import NODE_NAME, Target

ANSWER_TIMEOUT = 2.0
"""Seconds ``--live`` waits for the odometry of one scan when ``--timeout`` is not given."""


def answer_timeout(args: argparse.Namespace) -> float:
    """Return how long ``--live`` waits for one scan's odometry (``--timeout``)."""
    return ANSWER_TIMEOUT if args.timeout is None else float(args.timeout)


def live_target(args: argparse.Namespace) -> Target:
    """Return the node ``--live`` drives, as far as the options name it (the rest is found)."""
    return Target(args.namespace, args.node_name, args.scan_topic_out, args.odom_topic_in)


def params_node_name(args: argparse.Namespace) -> str:
    """Return the fully qualified node name the params file is read for (``/laser_odom``)."""
    return live_target(args).node_fqn() or '/' + (args.node_name or NODE_NAME).strip('/')
