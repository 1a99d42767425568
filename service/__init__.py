"""The ARCF tracking service: Zenoh transport, control plane, worker pool, Prometheus metrics.

A thin layer around the :mod:`arcf` library (which never imports this package). See
``docs/service-design.md`` and ``docs/wire-contract.md``.
"""
