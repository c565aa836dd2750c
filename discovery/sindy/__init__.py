"""Weak-form SINDy structure discovery of the actuator.

Pipeline stages, one module each:

* :mod:`.library` -- a pysindy feature library of the actuator nonlinearities (dead zone,
  saturation, friction sign, play-operator backlash, delayed command);
* :mod:`.weak` -- compact test functions and the weak (integral) form of the equation;
* :mod:`.forms` -- structure descriptions (where the dead zone, friction, band-pass loop and delay
  sit) and the weak regression columns each implies;
* :mod:`.estimator` -- :class:`WeakSINDyActuator`, the sklearn-style estimator with the threshold
  and delay scan, the information criterion and the bootstrap inclusion probabilities;
* :mod:`.candidates` -- :class:`Candidate`, a fitted proposal convertible to a models/ hypothesis;
* :mod:`.simulation` -- recordings' experiments rebuilt and scored against simulations;
* :mod:`.ranking` -- :func:`rank_by_simulation`, every proposal simulated as a full model.

:func:`discover_structure` runs the whole pipeline.
"""
from tvcid.models.recording import load_recordings

from .candidates import Candidate
from .estimator import DEFAULT_FORMS, WeakSINDyActuator
from .forms import FORMS, StructureForm, UnknownFormError, form_by_name
from .library import ACTUATOR_TERMS, ActuatorLibrary, play_along
from .ranking import rank_by_simulation
from .simulation import replay_experiment, waveform_distance
from .weak import BumpTestFunctions, RecordingTooShortError

__all__ = [
    "ACTUATOR_TERMS",
    "ActuatorLibrary",
    "BumpTestFunctions",
    "Candidate",
    "DEFAULT_FORMS",
    "FORMS",
    "RecordingTooShortError",
    "StructureForm",
    "UnknownFormError",
    "WeakSINDyActuator",
    "discover_structure",
    "form_by_name",
    "load_recordings",
    "play_along",
    "rank_by_simulation",
    "replay_experiment",
    "waveform_distance",
]


def discover_structure(recordings, noise=None, forms=DEFAULT_FORMS, seed=0, rank=True, **kwargs):
    """Fit every structure form to the recordings and rank the proposals by simulation.

    Parameters
    ----------
    recordings : path, Recording, or a sequence of them
    noise : float or None
        Sensor noise rms of ``delta`` (rad), for the bias-compensated normal equations.
    forms : sequence of str
    seed : int
        Seed of the bootstrap generator.
    rank : bool
        Simulate and rank (:func:`rank_by_simulation`); otherwise order by the weak criterion.
    **kwargs
        Further :class:`WeakSINDyActuator` arguments.

    Returns
    -------
    estimator : WeakSINDyActuator
        Fitted; ``estimator.candidates_`` is the ranked list.
    """
    est = WeakSINDyActuator(forms=forms, noise=noise, seed=seed, **kwargs).fit(recordings)
    if rank:
        est.candidates_ = rank_by_simulation(est.candidates_, est.recordings_)
    return est
