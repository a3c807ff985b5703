"""uvms_env: cooperative transport by several underwater vehicle-manipulator systems.

Layers, lowest first (a layer imports only those below it):
``models`` (parameters, URDF) -> ``dynamics`` (CasADi functions of one UVMS and of the
object) -> ``sim`` (closed-chain truth simulator) ; ``navigation`` (navigation function)
-> ``scenarios`` (validated task configs; used by ``sim``).

    from uvms_env.scenarios import make
    from uvms_env.sim import Simulator
    sim = Simulator(make("paper"))
"""

__version__ = "0.1.0"
