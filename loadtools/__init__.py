"""Load tools: simulated ground stations and the harness that runs the real service for them.

Nothing here is part of the server: :mod:`service` never imports this package. It is what the
console scripts ``arcf-loadtest`` and ``arcf-demo``, the benchmarks and the integration tests
share:

- :mod:`arcf.loadtools.driver`: **the** stream driver. A :class:`Fleet` of simulated drones, each
  replaying a :class:`Clip` of real JPEG frames under a :class:`Pacing` policy (fixed rate,
  closed loop, lock-step), with its tracking sessions.
- :mod:`arcf.loadtools.ledger`: **the** results ledger. Every frame sent and every result received,
  per stream, and what is read from them: latency percentiles, windows, the frame accounting,
  gaps and handovers, and the one capacity criterion (:func:`meets_capacity`).
- :mod:`arcf.loadtools.procs`: **the** way to spawn ``arcf-service`` and ``arcf-router``
  processes on free loopback ports.
- :mod:`arcf.loadtools.system`: CPU and memory of process trees, and the machine's description.
- :mod:`arcf.loadtools.loadtest` (``arcf-loadtest``), :mod:`arcf.loadtools.stress` (overload
  and soak runs) and :mod:`arcf.loadtools.demo` (``arcf-demo``): the tools built from those parts.
"""

from .driver import Clip, Fleet, Pacing, SimulatedStream
from .ledger import Ledger, Received, StreamRecord, meets_capacity, percentiles
from .procs import RouterProcess, ServiceProcess, free_port

__all__ = ["Clip", "Fleet", "Ledger", "Pacing", "Received", "RouterProcess", "ServiceProcess",
           "SimulatedStream", "StreamRecord", "free_port", "meets_capacity", "percentiles"]
