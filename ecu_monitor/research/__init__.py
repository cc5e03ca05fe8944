"""Research and evaluation above the runtime: what the paper's claims and our detector measure on the
virtual ECU.

:mod:`~ecu_monitor.research.paper` reproduces the paper's Section 3.2 (``ecu-monitor results``),
:mod:`~ecu_monitor.research.evaluation` runs the detection and isolation campaign (``ecu-monitor
evaluate``) and :mod:`~ecu_monitor.research.blind` the gap diagnosis's blind cases (``ecu-monitor gap
--blind N``). Besides the commands and the tests, this is the only package that flies the virtual ECU
(``virtual_bus``); the service never imports it. Plots need the ``research`` extra (matplotlib, tqdm).
"""
