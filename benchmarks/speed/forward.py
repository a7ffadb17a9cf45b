"""The forward solve: the 20-link cantilever, the gallery robots, growth with the links, and
warm-started re-solves as a control loop makes them."""

from __future__ import annotations

import numpy as np

from ._robots import active_actuation, model_of

# gallery scenes the runtime builds as they are (cbha_design holds design segments: `prepare`)
RUNTIME_SCENES = ("cantilever", "paper_3v_4t", "paper_3v_8t", "paper_5v_16t", "polymer_5v_16t",
                  "tendon_two_section")


class Cantilever20:
    """The gallery cantilever (20 links, dead tip load) solved from rest."""

    def setup(self):
        self.model = model_of("cantilever")
        self.model.solve()

    def time_solve(self):
        self.model.solve()

    def track_iterations(self):
        return self.model.solve().iterations

    track_iterations.unit = "iterations"


class Gallery:
    """Each runtime gallery scene from rest; the tendon robots with 3 N on every fourth tendon
    where the scene's own actuation is zero."""

    params = RUNTIME_SCENES
    param_names = ["scene"]

    def setup(self, scene):
        self.model = model_of(scene)
        self.actuation = active_actuation(self.model) if self.model.n_cables + self.model.n_chambers else None
        self.model.solve(self.actuation)

    def time_solve(self, scene):
        self.model.solve(self.actuation)

    def track_iterations(self, scene):
        return self.model.solve(self.actuation).iterations

    track_iterations.unit = "iterations"


class Scaling:
    """A steel cantilever (r = 1 mm, L = 0.5 m, PL²/EI = 1) of 10 to 3,000 links: the cost per
    Newton iteration should grow linearly with the frames."""

    params = [10, 100, 1000, 3000]
    param_names = ["links"]
    timeout = 120

    def setup(self, links):
        from vertebra import solver

        E, radius, length = 200e9, 1e-3, 0.5
        force = E * np.pi * radius ** 4 / 4 / length ** 2
        self.model = solver.build_model(solver.parse_scene({
            "name": f"cantilever-{links}", "solver": {"tolerance": 1e-9, "max_iterations": 100},
            "segment": [{"type": "beam", "count": 1, "length": length, "elements": int(links),
                         "youngs_modulus": E, "poisson_ratio": 0.3,
                         "section": {"shape": "circle", "radius": radius}}],
            "load": [{"vertebra": -1, "force": [force, 0.0, 0.0]}]}))
        self.result = self.model.solve()

    def time_solve(self, links):
        self.model.solve()

    def time_linearise(self, links):
        self.model.linearise(self.result.state, self.model.default_actuation)

    def track_iterations(self, links):
        return self.result.iterations

    track_iterations.unit = "iterations"

    def peakmem_solve(self, links):
        self.model.solve()


class WarmStart:
    """A re-solve after a 1 % change of the tendon tensions, started from the previous
    equilibrium (``initial=``) and from rest."""

    params = ("tendon_two_section", "paper_5v_16t")
    param_names = ["scene"]

    def setup(self, scene):
        self.model = model_of(scene)
        self.before = active_actuation(self.model)
        self.after = 1.01 * self.before
        self.previous = self.model.solve(self.before).state
        self.model.solve(self.after, initial=self.previous)

    def time_warm(self, scene):
        self.model.solve(self.after, initial=self.previous)

    def time_cold(self, scene):
        self.model.solve(self.after)

    def track_warm_iterations(self, scene):
        return self.model.solve(self.after, initial=self.previous).iterations

    track_warm_iterations.unit = "iterations"
