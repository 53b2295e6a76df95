"""The ROS 1 graph from the master's XML-RPC API, with liveness from each node itself.

The master only knows what nodes registered; a node killed with SIGKILL stays registered.
So every node is asked for its pid through its own slave API on every round
(:mod:`blackbox.sources.ros1.slave_probe`): a node that refuses or does not answer in time
is reported dead whatever the master says. Nothing here registers anything anywhere, so
the robot never sees the black box in its graph.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import psutil

from blackbox.events import GraphSnapshot, NodeInfo, TopicInfo
from blackbox.sources.ros1.callerid import is_black_box
from blackbox.sources.ros1.master import (
    MasterClient,
    Report,
    RosApiError,
    SystemState,
    host_of,
    probe_pid,
)
from blackbox.sources.ros1.resources import is_local_host
from blackbox.sources.ros1.slave_probe import NodeReply, SlaveProbe

HUNG_LIMIT = 5.0
"""Seconds a node whose API does not answer the quick probe counts as running on the
strength of a late answer or (a local node) of its running process; past that it is hung."""

LATE_TIMEOUT = 5.0
"""Seconds a second, patient probe waits for a node that did not answer the quick one."""

_NOT_RUNNING = frozenset({psutil.STATUS_STOPPED, psutil.STATUS_TRACING_STOP,
                          psutil.STATUS_ZOMBIE, psutil.STATUS_DEAD})


@dataclass(slots=True)
class NodeState:
    """What the poller knows about one node between rounds."""

    name: str
    uri: str | None = None
    alive: bool = False
    pid: int | None = None
    reason: str = "not yet probed"
    registered: bool = True
    unbatched_rounds: int = 0
    """Rounds left without extra calls: after ``system.multicall`` failed as a whole the
    node is asked for its pid alone for a while (``GraphPoller.batch_pause``)."""
    unanswered_since: float | None = None
    """Monotonic time of the first of the probes in a row that got no answer in time."""
    late_answer: float | None = None
    """Monotonic time of the latest answer to a patient probe (``LATE_TIMEOUT``)."""
    late_probe: bool = False
    """A patient probe of this node is under way."""


class GraphPoller:
    """Builds :class:`GraphSnapshot` s from the master plus a liveness probe of every node.

    When the master is unreachable the last known topics are kept and the known nodes are
    still probed directly, so liveness keeps working through a master restart.

    A node whose probe got no answer in time (a refused connection is death) is still
    running, only slow to answer, when

    * messages of its publications arrived after the probe was sent (``heard_from(node)``:
      the wall-clock kernel time of its latest message; a stopped or dead process sends
      nothing), or
    * it answered a patient probe (sent beside the rounds, waiting ``LATE_TIMEOUT`` s)
      within the last ``HUNG_LIMIT`` s: it answers, only late, or
    * its process runs on this machine and is not stopped, for at most ``HUNG_LIMIT`` s of
      unanswered probes (a machine so busy that the node's XML-RPC thread gets no CPU for
      half a second is not a dead node; a process that stays silent longer is hung).

    It then stays alive, and ``slow_api`` is reported once.
    """

    def __init__(self, master_uri: str, report: Report, probe_timeout: float = 0.5,
                 master_timeout: float = 1.0, max_workers: int = 8,
                 master_period: float = 1.0,
                 heard_from: Callable[[str], float | None] | None = None) -> None:
        self.master = MasterClient(master_uri, master_timeout)
        self._report = report
        self._heard_from = heard_from
        self._slow: set[str] = set()
        """Nodes currently alive by their messages while their API does not answer in time."""
        self._probe_timeout = probe_timeout
        self._slaves = SlaveProbe()
        self._late_pool = ThreadPoolExecutor(max_workers=2,
                                             thread_name_prefix="ros1-late-probe")
        self._pool = ThreadPoolExecutor(max_workers=max_workers,
                                        thread_name_prefix="ros1-probe")
        self.nodes: dict[str, NodeState] = {}
        self.state = SystemState()
        self.types: dict[str, str] = {}
        self.master_ok: bool | None = None
        self._master_period = master_period
        self._next_master = 0.0
        self._registered: set[str] = set()
        self.batch_pause = 20
        """Rounds (about 9 s) a node whose batch failed is asked for its pid alone."""
        self.replies: dict[str, NodeReply] = {}
        """This round's replies of the nodes asked extra calls (see :meth:`refresh`)."""

    def close(self) -> None:
        self._pool.shutdown(wait=False, cancel_futures=True)
        self._late_pool.shutdown(wait=False, cancel_futures=True)
        self._slaves.close()

    def uri_of(self, node: str) -> str | None:
        st = self.nodes.get(node)
        return st.uri if st is not None else None

    def refresh(self, extra: Mapping[str, tuple[str, ...]] | None = None) -> None:
        """One round: probe every node, and ask the master every ``master_period`` s.

        ``extra``: slave API methods to call on some nodes in the same request as the
        probe; their answers are in :attr:`replies` until the next round.

        Liveness needs a fast probe; the graph's structure changes rarely, so the master
        is asked less often (and every round while it is unreachable).

        A node that is still alive but no longer registered (the master restarted; rospy
        and roscpp nodes do not register again) keeps its last known topics.
        """
        previous = self.state
        fresh = None
        now = time.monotonic()
        if now >= self._next_master or self.master_ok is not True:
            self._next_master = now + self._master_period
            fresh = self._refresh_master()
        if fresh is not None:
            self._registered = {n for n in fresh.node_names() if not is_black_box(n)}
        for name in self._registered - self.nodes.keys():
            self.nodes[name] = NodeState(name)
        for name, st in self.nodes.items():
            st.registered = name in self._registered
        self._probe(list(self.nodes.values()), extra or {})
        for name in [n for n, st in self.nodes.items() if not st.registered and not st.alive]:
            del self.nodes[name]
        if fresh is None:
            return
        orphans = {n for n, st in self.nodes.items() if st.alive and not st.registered}
        for group, old in ((fresh.publishers, previous.publishers),
                           (fresh.subscribers, previous.subscribers)):
            for topic, members in old.items():
                kept = orphans.intersection(members)
                if kept:
                    group[topic] = tuple(sorted(kept.union(group.get(topic, ()))))
        self.state = fresh

    def snapshot(self, now: float) -> GraphSnapshot:
        """The robot's graph; black boxes (this one's ``/diagnostics`` publisher, other
        black boxes) are left out: they are not part of the robot."""
        nodes = {n: NodeInfo(n, st.alive, st.pid if st.alive else None,
                             host_of(st.uri) if st.uri else None)
                 for n, st in sorted(self.nodes.items()) if not is_black_box(n)}
        topics: dict[str, TopicInfo] = {}
        for t in sorted(self.state.publishers.keys() | self.state.subscribers.keys()):
            pubs = tuple(n for n in self.state.publishers.get(t, ()) if not is_black_box(n))
            subs = tuple(n for n in self.state.subscribers.get(t, ()) if not is_black_box(n))
            if pubs or subs:
                topics[t] = TopicInfo(t, self.types.get(t, ""), pubs, subs)
        return GraphSnapshot(now, nodes, topics)

    def _refresh_master(self) -> SystemState | None:
        """The master's current state, or ``None`` (and a report) when it is unreachable."""
        try:
            state = self.master.system_state()
            topics = state.publishers.keys() | state.subscribers.keys()
            if not topics <= self.types.keys() or self.master_ok is not True:
                self.types.update(self.master.topic_types())
        except RosApiError as exc:
            if self.master_ok is not False:
                self._report("master_lost", self.master.uri,
                             f"ROS master unreachable, keeping the last known graph: {exc}")
            self.master_ok = False
            return None
        if self.master_ok is False:
            self._report("master_back", self.master.uri, "ROS master reachable again")
        self.master_ok = True
        return state

    def _probe(self, states: Iterable[NodeState],
               extra: Mapping[str, tuple[str, ...]]) -> None:
        states = list(states)
        sent = time.time()
        batched = {n: m for n, m in extra.items()
                   if n in self.nodes and self.nodes[n].unbatched_rounds == 0}
        for st in states:
            st.unbatched_rounds = max(0, st.unbatched_rounds - 1)
        replies = self._slaves.probe({st.name: st.uri for st in states if st.uri},
                                     self._probe_timeout, batched)
        self.replies = {n: r for n, r in replies.items() if r.extra}
        for name, reply in replies.items():
            if not reply.multicall:
                self.nodes[name].unbatched_rounds = self.batch_pause
        quick = {n: r.pid for n, r in replies.items()}
        slow = [(st, self._pool.submit(self._probe_one, st, quick.get(st.name)))
                for st in states if not isinstance(quick.get(st.name), int)]
        results: dict[str, int | Exception] = {
            n: r for n, r in quick.items() if isinstance(r, int)}
        for st, fut in slow:
            try:
                results[st.name] = fut.result()
            except Exception as exc:  # a probe must never take the poller down
                results[st.name] = exc
        for st in states:
            was_alive, old_reason = st.alive, st.reason
            result = results[st.name]
            if isinstance(result, int):
                st.pid, st.alive, st.reason = result, True, ""
                st.unanswered_since = None
                if st.name in self._slow:
                    self._slow.discard(st.name)
                    self._report("api_answers", st.name, f"node {st.name} answers its "
                                 f"slave API in time again (pid {st.pid})")
            elif not self._running_by_messages(st, sent, result):
                self._slow.discard(st.name)
                st.alive = False
                st.reason = (str(result) if isinstance(result, RosApiError)
                             else f"probe failed: {result!r}")
            if was_alive and not st.alive:
                self._report("node_dead", st.name, f"node {st.name} stopped answering its "
                             f"slave API: {st.reason}")
            elif st.alive and not was_alive and old_reason != "not yet probed":
                self._report("node_alive", st.name, f"node {st.name} answers again "
                             f"(pid {st.pid})")

    def _running_by_messages(self, st: NodeState, sent: float,
                             error: int | Exception) -> bool:
        """A node whose probe failed but that is running all the same (see the class):
        slow to answer (reported once until it answers in time again)."""
        why = self._running_anyway(st, sent, error)
        if why is None:
            return False
        st.alive, st.reason = True, f"slow to answer its slave API ({error}); {why}"
        if st.name not in self._slow:
            self._slow.add(st.name)
            self._report("slow_api", st.name,
                         f"node {st.name} does not answer its slave API within "
                         f"{self._probe_timeout:g} s ({error}), but {why}: running, "
                         "slow to answer")
        return True

    def _running_anyway(self, st: NodeState, sent: float, error: int | Exception
                        ) -> str | None:
        if "timed out" not in str(error):
            st.unanswered_since = None
            return None
        now = time.monotonic()
        if st.unanswered_since is None:
            st.unanswered_since = now
        self._probe_late(st)
        status = self._local_status(st)
        if status in _NOT_RUNNING:  # stopped or gone: nothing else makes it run
            return None
        heard = self._heard_from(st.name) if self._heard_from is not None else None
        if heard is not None and heard > sent:
            return "its messages keep arriving"
        if st.late_answer is not None and now - st.late_answer <= HUNG_LIMIT:
            return f"it answered {now - st.late_answer:.1f} s ago, late"
        if status is not None and st.alive and now - st.unanswered_since <= HUNG_LIMIT:
            return f"its process {st.pid} runs on this machine ({status})"
        return None

    @staticmethod
    def _local_status(st: NodeState) -> str | None:
        """The state of a local node's process (``psutil`` status; ``dead`` when it is
        gone), ``None`` for a remote node or one whose pid is not known."""
        if st.pid is None or not st.uri or not is_local_host(host_of(st.uri)):
            return None
        try:
            return str(psutil.Process(st.pid).status())
        except psutil.NoSuchProcess:
            return str(psutil.STATUS_DEAD)
        except psutil.AccessDenied:
            return None

    def _probe_late(self, st: NodeState) -> None:
        """Ask ``st`` once more, patiently, beside the rounds (one such probe at a time)."""
        if st.late_probe or not st.uri:
            return
        st.late_probe = True
        uri = st.uri

        def probe() -> None:
            try:
                pid = probe_pid(uri, LATE_TIMEOUT)
                if st.uri == uri:
                    st.late_answer = time.monotonic()
                    st.pid = st.pid if st.pid is not None else pid
            except Exception:  # no answer: nothing learnt
                pass
            finally:
                st.late_probe = False

        try:
            self._late_pool.submit(probe)
        except RuntimeError:  # shut down
            st.late_probe = False

    def _probe_one(self, st: NodeState, first: int | RosApiError | None) -> int:
        """After a failed quick probe: look the node up again (it may have restarted)."""
        first_error = first if isinstance(first, RosApiError) else None
        if self.master_ok is False or not st.registered:
            raise first_error or RosApiError(f"{st.name}: no slave URI known")
        try:
            uri = MasterClient(self.master.uri, self._probe_timeout).lookup_node(st.name)
        except RosApiError as exc:
            raise first_error or exc from None
        if uri == st.uri and first_error is not None:
            raise first_error
        if uri != st.uri:
            st.uri, st.unbatched_rounds = uri, 0
        return probe_pid(uri, self._probe_timeout)


