"""Timing benchmarks behind ``chirplidar bench --what ...`` (``make bench``).

- :mod:`.timing`: an rf shot against one FFT (``shot``), each effect on and off (``effects``),
  seconds per shot of every tier (``tiers``).
- :mod:`.scale`: a survey serially and on 2 Dask workers (``scale``), the 91-day satellite
  campaign (``campaign``).
- :mod:`.coverage`: ``chirplidar coverage`` on generated 10 M and 20 M shot files (``coverage``).
- :mod:`.startup`: ``chirplidar --help`` and ``import chirplidar.units`` in fresh processes
  (``startup``).

The accuracy-versus-time study (``accuracy``) is :mod:`chirplidar.analysis.accuracy` and the ray
casting benchmark (``raycast``) :mod:`chirplidar.benchmarks.raycast`. Modules are imported
by the command that runs them; none is imported here.
"""
