"""Studies at scale: thousands to millions of exact-plant trajectories, on a Dask cluster.

* :mod:`.design`: what a study runs, a grid or a Monte Carlo design, every trajectory's parameters a pure
  function of its index (seeds from the index, never from call order);
* :mod:`.chunk`: one chunk of a study's trajectories on the batched engine, reduced to a tidy table;
* :mod:`.table`: the Parquet table, one file per chunk;
* :mod:`.engine`: the Dask client (a local cluster by default, or ``--scheduler``), chunks written as
  they arrive, ``--resume``, retries, progress;
* :mod:`.sweep` and :mod:`.robustness`: the studies of ``tdslip sweep`` and ``tdslip robustness``
  (their command lines: :mod:`tdslip_ros.commands`).

No ROS here: the package uses the model core, and the output and style of :mod:`tdslip_ros.reporting`.
"""
