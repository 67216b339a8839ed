"""One substitution analysis in memory: record -> spectra -> model-free -> law fits -> ranking."""
from __future__ import annotations

from dataclasses import dataclass

from mbus_framework.substitution.fit import LawFit, SubstitutionProblem, checks, fit_law
from mbus_framework.substitution.chains import any_law
from mbus_framework.substitution.model_free import Dispersion, model_free
from mbus_framework.substitution.record import SubstitutionRecord
from mbus_framework.substitution.spectra import Spectra, spectra
from mbus_framework.substitution.water import Water


@dataclass
class SubstitutionAnalysis:
    record: SubstitutionRecord
    water: Water
    spectra: Spectra
    model_free: Dispersion
    fits: list[LawFit]  # best (lowest BIC) first

    @property
    def best(self) -> LawFit:
        return self.fits[0]

    def checks(self, fit: LawFit | None = None) -> list[dict]:
        return checks(fit or self.best, self.model_free)

    def passed(self, fit: LawFit | None = None) -> bool:
        return all(r.get("velocity_ok", True) and r.get("attenuation_ok", True) for r in self.checks(fit))


def analyse(record: SubstitutionRecord, laws=("constant_q",), *, reverberations: bool = True,
            band_dB: float = 30.0) -> SubstitutionAnalysis:
    """Model-free dispersion of ``record`` and each law fitted to it, ranked by BIC."""
    water = Water.at(record.temperature_C)
    sp = spectra(record, band_dB)
    reference = model_free(sp, record.density, record.thickness, water, record.passes, reverberations)
    problem = SubstitutionProblem(sp, record.density, record.thickness, water, record.passes, reverberations)
    fits = sorted((fit_law(problem, any_law(name), reference) for name in laws), key=lambda x: x.bic)
    return SubstitutionAnalysis(record, water, sp, reference, fits)
