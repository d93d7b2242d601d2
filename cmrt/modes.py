"""The named choices of cmrt: constants only, no imports.

The controller (``cmrt.control.references``), the task record (``cmrt.motion.task``), the evaluators
(``cmrt.optimize.parallel``) and the command line (``--reference``, ``--backend``) read these one
definitions; building the command line imports nothing heavy for them.
"""

#: Where the momentum controller's reference CoM and CoP come from (``cmrt.control.references``): the support
#: centre (Macchietto; ABC) or the GRF-weighted feet and Winter's CoP (Yu eq. 3.2-3.4).
REFERENCE_MODES = ("center", "yu")
#: A task's mode when its file names none (left out of the task's dict then: older content hashes stay valid).
DEFAULT_REFERENCE_MODE = "center"

#: Evaluation backends of ``cmrt.optimize.parallel.Evaluator``.
BACKENDS = ("batch", "serial", "loky", "loky+batch", "dask", "dask+batch")
