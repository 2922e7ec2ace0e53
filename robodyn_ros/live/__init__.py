"""Watch and steer a run live: a Foxglove WebSocket server fed by the run's recorder.

* :mod:`.server`: the server (both dialects of the protocol, ``foxglove.websocket.v1`` and
  ``foxglove.sdk.v1``), on its own thread, bounded per client;
* :mod:`.steering`: what clients send back (commands, ``reset``/``pause``, ``rate_factor``), handed
  to the simulation's thread and checked there like ROS messages;
* :mod:`.run`: ``robodyn run --live``: the pacing and steering sink of a headless run.

The node (:mod:`robodyn_ros.nodes.sim`, parameter ``foxglove_port``) uses the server and steering.
Nothing here is imported unless live is on (it needs the ``websockets`` package).
"""
