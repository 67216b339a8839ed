"""The immersion substitution method: a plate in water, a reference shot without it.

Data flow: :mod:`.record` (reference and sample shots, geometry, water) -> :mod:`.spectra`
(in-band lines of both shots) -> :mod:`.model_free` (phase velocity and attenuation straight from
the spectral ratio) and :mod:`.fit` (a material law's complex modulus fitted to the same lines)
-> :mod:`.report` (result.json, dispersion figure, printed summary). :mod:`.command` runs it from
a config (``experiment: substitution``).
"""
