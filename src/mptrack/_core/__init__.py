"""The private layer every package may import: the numerical cores and the shared infrastructure.

Nothing here is public API.  A module belongs here when two or more packages need it and no package
owns its concept (a module with a single user package lives in that package; docs/design.md, Layout).

Numerical cores (compiled or NumPy; each tested against a readable reference):

* :mod:`.kalman`   the compiled Kalman predict and update every compiled Gaussian filter calls
                   (its docstring lists the places that keep their own Kalman algebra, and why)
* :mod:`.rts`      the Rauch-Tung-Striebel backward pass
* :mod:`.unscented`  sigma points and weights of the unscented transform
* :mod:`.van_loan`   exact discretisation of continuous linear models
* :mod:`.gaussian`   angle wrapping and Gaussian log-densities
* :mod:`.lyapunov`   power sums (F^N, sum F^j Q F^jT) by repeated squaring
* :mod:`.fir`        steady-state FIR coefficients

Shared infrastructure:

* :mod:`.validation`  argument checks that raise :mod:`mptrack.errors` naming the argument
* :mod:`.data_checks`  data files and tables as arguments; outputs that must not overwrite an input
* :mod:`.finiteness`  finite results or clear errors; errors relabelled with the caller's names
* :mod:`.float_scan`, :mod:`.threads`  compiled finiteness scans and their thread launch
* :mod:`.files`       atomic files (complete on disk or absent)
* :mod:`.jit_cache`   where numba caches compiled kernels
* :mod:`.moved`       old import paths served for one release with a DeprecationWarning
* :mod:`.tracks`      track offsets of a table sorted by track
* :mod:`.model_families`, :mod:`.filter_inputs`  the model types the nonlinear filters run and
  their argument handling
* :mod:`.steady_input`  the ``steady=`` argument of the steady-state filters (solved once per model)
* :mod:`.blas`        small dense linear algebra on one BLAS thread (Riccati solves, model fits)
"""
