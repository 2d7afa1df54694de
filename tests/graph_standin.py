"""A CPU stand-in for CUDA graphs, for the tests of ``render.graphs`` (Triton's interpreter has no graphs): the real
engine (``render.graphs._CudaGraphReplay``: its copies in, static outputs, backward replay and gradient hand-off)
with each capture replaced by a rerun of the captured work that writes its results into the capture's tensors -
what a graph's replay does in place."""

from cylindersplat.render import graphs


class RerunGraph:
    """A captured graph's stand-in: ``replay()`` runs the work again and copies its results into the first run's."""

    def __init__(self, work):
        self._work = work
        self.result = self.latest = work()

    def replay(self):
        self.latest = self._work()
        for mine, new in zip(self.result, self.latest):
            if mine is not None and new is not None:
                mine.detach().copy_(new.detach())


class RerunGraphReplay(graphs._CudaGraphReplay):
    """:class:`render.graphs._CudaGraphReplay` on :class:`RerunGraph` (no side stream, no memory pool); the backward
    differentiates the latest forward rerun's outputs (a graph's backward reads what its forward replay saved)."""

    def _warm_up(self, forward, gradients):
        pass

    def _pool(self):
        return None

    def _captured(self, work, pool):
        graph = RerunGraph(work)
        return graph, graph.result

    def _graph_outputs(self):
        return self._forward.latest
