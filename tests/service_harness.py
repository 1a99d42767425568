"""The integration tests' service and router processes (see :mod:`service.procs`)."""

from service.procs import RouterProcess, ServiceProcess, free_port, worker_pids

__all__ = ["RouterProcess", "ServiceProcess", "free_port", "worker_pids"]
