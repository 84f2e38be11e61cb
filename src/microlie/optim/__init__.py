"""Factor graphs on groups and pose-graph files.

File readers and writers: :mod:`microlie.optim.g2o`, :mod:`microlie.optim.toro`
(both return a :class:`microlie.optim.pose_graph.PoseGraph`); initialisation:
:mod:`microlie.optim.init`.
"""
