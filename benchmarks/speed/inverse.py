"""The inverse: the model's linearisation, the constraint-space projection (W), the QP and the
retraction of one step, and the whole tick of the controller, from a fixed state and in a
control loop."""

from __future__ import annotations

import numpy as np

from ._robots import TICK_SCENES, circle_targets, model_of, tick_start


def _controller(bench, scene: str, mode: str) -> None:
    """``bench.model``, its fixed state (``lam``, ``state``, ``targets``) and an inverse
    controller in ``mode`` starting there."""
    from vertebra.solver.inverse import InverseController, InverseSettings

    bench.model = model_of(scene)
    bench.lam, bench.state, bench.targets = tick_start(bench.model)
    bench.controller = InverseController(bench.model, InverseSettings(mode=mode), actuation=bench.lam,
                                         state=bench.state)


class Tick:
    """``InverseController.step`` in tick mode (one linearise–project–QP–step per call).

    ``time_same_state``: every tick from the same state and actuation towards targets 1 mm off;
    ``time_loop``: a control loop, each tick from where the last one left, the targets moving
    on a 1 mm circle (one turn per 100 ticks)."""

    params = TICK_SCENES
    param_names = ["scene"]

    def setup(self, scene):
        _controller(self, scene, "tick")
        self.loop = circle_targets(self.model.effector_positions(self.state), 100)
        self.k = 0
        for _ in range(20):
            self._same_state()
        self.controller.state, self.controller.actuation = self.state, self.lam
        for _ in range(20):
            self._loop()

    def _same_state(self):
        self.controller.state, self.controller.actuation = self.state, self.lam
        return self.controller.step(self.targets)

    def _loop(self):
        self.k += 1
        return self.controller.step(self.loop[self.k % len(self.loop)])

    def time_same_state(self, scene):
        self._same_state()

    def time_loop(self, scene):
        self._loop()


class Converged:
    """``InverseController.step`` in converged mode towards targets 1 mm off the fixed state."""

    params = TICK_SCENES
    param_names = ["scene"]

    def setup(self, scene):
        _controller(self, scene, "converged")

    def time_step(self, scene):
        self.controller.state, self.controller.actuation = self.state, self.lam
        self.controller.step(self.targets)


class Pieces:
    """The pieces of a tick, each alone through its public function: the linearisation (tangent
    and banded factor), ``ConstraintSpace.project`` (K⁻¹[r, B] and W), the QP
    (``solve_constraint_problem``, DAQP) and the retraction."""

    params = TICK_SCENES
    param_names = ["scene"]

    def setup(self, scene):
        from vertebra.solver.inverse import ConstraintSpace, solve_constraint_problem

        self.model = model_of(scene)
        self.lam, self.state, self.targets = tick_start(self.model)
        self.space = ConstraintSpace.of_model(self.model)
        self.lin = self.model.linearise(self.state, self.lam)
        self.projection = self.space.project(self.lin, self.targets, self.lam)
        self.solve_qp = solve_constraint_problem
        solution = solve_constraint_problem(self.projection.problem)
        self.change = self.projection.state_change(solution.actuation)

    def time_linearise(self, scene):
        self.model.linearise(self.state, self.lam)

    def time_project(self, scene):
        self.space.project(self.lin, self.targets, self.lam)

    def time_qp(self, scene):
        self.solve_qp(self.projection.problem)

    def time_step(self, scene):
        self.model.step(self.state, self.change)


def _qp_cases():
    return ["4x3", "16x3", "16x6", "32x6"]


class QP:
    """The constraint-space QP of synthetic problems built like the real ones (SPD K, cables
    with B = −Jaᵀ; seeded), actuators × effector rows, targets out of reach, every backend."""

    params = (_qp_cases(), ["daqp", "gauss-seidel", "qpsolvers:clarabel", "qpsolvers:daqp"])
    param_names = ["actuators x rows", "backend"]

    def setup(self, case, backend):
        from vertebra.solver.inverse import (ConstraintProblem, ConstraintSpace, available_backends,
                                             solve_constraint_problem)
        from vertebra.solver.inverse.problems import synthetic_problem

        if backend not in available_backends():
            raise NotImplementedError(f"backend {backend} is not installed")
        n_act, n_rows = (int(v) for v in case.split("x"))
        W_ea, de, W_aa, _ = synthetic_problem(0, n_act, n_rows, reach=3.0)
        space = ConstraintSpace(n_act, n_rows, lambda_lower=0.0, lambda_upper=20.0)
        self.problem = ConstraintProblem(space, W_ea, de, W_aa, np.zeros(n_act))
        self.backend = backend
        self.solve_qp = solve_constraint_problem
        solve_constraint_problem(self.problem, backend)

    def time_solve(self, case, backend):
        self.solve_qp(self.problem, self.backend)


class ModelTick:
    """The model's part of a control tick on ``paper_5v_16t``, ticking on from state to state
    with the tensions moving ±1 %: the linearisation, ``K⁻¹[r, B]`` (one banded solve of
    1 + actuators right-hand sides), the retraction and the effector positions."""

    def setup(self):
        from ._robots import active_actuation

        self.model = model_of("paper_5v_16t")
        self.lam = active_actuation(self.model)
        self.change = 0.01 * self.lam
        self.state = self.model.solve(self.lam).state
        self.k = 0
        for _ in range(20):
            self.time_tick()

    def time_tick(self):
        model, state, lam = self.model, self.state, self.lam
        lin = model.linearise(state, lam)
        rhs = np.empty((model.n_dof, 1 + lam.size), order="F")
        rhs[:, 0] = lin.residual
        rhs[:, 1:] = lin.actuator_forces
        X = lin.solve(rhs)
        d_lam = self.change if self.k % 2 == 0 else -self.change
        self.state = model.step(state, X[:, 0] + X[:, 1:] @ d_lam)
        model.effector_positions(self.state)
        self.lam, self.k = lam + d_lam, self.k + 1
