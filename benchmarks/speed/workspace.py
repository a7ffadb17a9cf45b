"""Workspace sampling of the 16-tendon paper robot (a small map, one process)."""

from __future__ import annotations

from ._robots import model_of


class Workspace:
    """``sample_workspace`` of ``paper_5v_16t`` with 200 Sobol samples in this process, by solve
    order (each sample starts from the Euler prediction off its parent's equilibrium)."""

    params = ("tree", "chain")
    param_names = ["ordering"]
    number = 1
    repeat = (1, 5, 30.0)
    timeout = 180

    def setup(self, ordering):
        from vertebra.solver.workspace import sample_workspace

        self.model = model_of("paper_5v_16t")
        self.sample = sample_workspace

    def time_sample_200(self, ordering):
        self.sample(self.model, 200, ordering=ordering, workers=1)

    def track_iterations_per_sample(self, ordering):
        workspace = self.sample(self.model, 200, ordering=ordering, workers=1)
        return float(workspace.iterations[workspace.converged].mean())

    track_iterations_per_sample.unit = "iterations"
