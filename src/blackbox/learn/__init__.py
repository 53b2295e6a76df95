"""``blackbox learn``: nominal models of a robot from a healthy run.

Watch a robot through any :class:`~blackbox.sources.base.Source` for a while, then write a
native configuration that observes what was seen: rates, time-outs, message ages, numeric
fields and array summaries, node liveness, CPU and memory, and the graph as the diagnosis
model. The rules are in docs/learn.md.

.. code-block:: python

    from blackbox.learn import learn_from, render_config
    learned = learn_from(lambda: open_source("ros1"), duration=600)
    text = render_config(learned, robot_id="my-robot", model_file="robot.model.yaml",
                         when="2026-11-23T09:00Z")
"""

from __future__ import annotations

from collections.abc import Callable

from blackbox.learn.model import Block, Learned, learn_model
from blackbox.learn.recording import Progress, Recording, discover_graph, record
from blackbox.learn.render import render_config, render_model
from blackbox.learn.update import update_config
from blackbox.sources.base import Source

DISCOVERY_TIMEOUT = 10.0


def learn_from(open_robot: Callable[[], Source], duration: float, *,
               progress: Progress | None = None, discovery_timeout: float = DISCOVERY_TIMEOUT,
               stop: Callable[[], bool] | None = None) -> Learned:
    """Discover the robot's graph, watch it for ``duration`` seconds and learn from that.

    ``open_robot`` opens a fresh source each time it is called (discovery and the learning
    run each use one). A robot with no graph at all still gives a :class:`Learned` whose
    notes say why nothing was learned.
    """
    troubles: list[str] = []
    graph = discover_graph(open_robot(), discovery_timeout, troubles=troubles)
    if graph is None or not (graph.nodes or graph.topics):
        # nothing to watch: say why at once instead of waiting out the learning run
        unused = open_robot()
        unused.close()
        learned = learn_model(Recording(unused.name, 0.0))
        what = "no graph snapshot" if graph is None else "no node and no topic"
        why = f" ({'; '.join(troubles)})" if troubles else ""
        learned.notes.insert(0, f"the source showed {what} within {discovery_timeout:g} s "
                                f"of discovery{why}")
        return learned
    recording = record(open_robot(), graph, duration, progress, stop=stop)
    return learn_model(recording)


__all__ = ["Block", "Learned", "Progress", "Recording", "learn_from", "learn_model",
           "record", "render_config", "render_model", "update_config"]
