"""depthguard's lab, beside the library: simulated workcells with exact ground truth (:mod:`depthguard_lab.simulation`),
the reference scenarios and experiments that judge the library (:mod:`depthguard_lab.experiments`), and the
``depthguard-lab`` command line (the demo among them). It imports only depthguard's public names.
"""

__version__ = "0.1.0"
