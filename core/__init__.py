"""The kernel layer: what every other vertebra package stands on, importing only numpy and scipy.

* :mod:`~vertebra.core.errors` — the domain exceptions (libraries raise them, only ``cli``
  turns them into exit codes);
* :mod:`~vertebra.core.lie` — quaternions, SO(3) and SE(3): exp, log, their Jacobians, ``hat``;
* :mod:`~vertebra.core.energy` — the fitted segment energy ψ(ξ, p): its definition, the linear
  part fixed by the compliance, and its batched evaluation kernel.

``core`` imports nothing else of vertebra; ``store``, ``designer`` and ``solver`` import it.
"""
