"""Pure numpy/scipy model of the TD-SLIP hopper. No ROS imports anywhere below this package.

SI units and the sign convention of :mod:`tdslip_ros.model.params` hold throughout;
:mod:`tdslip_ros.model.units` converts to the paper's dimensionless units.
"""
