"""Saying why: the counted, throttled lines about the global search, rejections, ambiguity.

When the global search runs (and why: a gap, a rejection, a failed local match), when a
match is rejected (with the correction against its gate and what the odometry does
instead) and when a match is ambiguous (with the alternative's distance and fit), the
user reads it once per period (:class:`.events.EventLog`) and the diagnostics count it.
Routine searches (the first match, ``prior: none``, ``global_search: always``) are
counted, not said.
"""

from __future__ import annotations

import math

import numpy as np

from laser_odom.core import se2
from laser_odom.core.configuration.pipeline import PipelineConfig
from laser_odom.core.events import EventLog
from laser_odom.core.registration.acceptance import MatchVerdict
from laser_odom.core.registration.registrar import Registration, ROUTINE_TRIGGERS, SEARCH_TRIGGERS
from laser_odom.core.registration.rejection import describe_rejection

PREDICTION_SOURCES = {'prior': 'the prediction (the prior)',
                      'last_step': "the last well-constrained step's motion (steady rate)"}
"""What stood in for a blind direction, by :attr:`.Prediction.source`."""

EVIDENCE_EVENTS = ('weakly_constrained', 'poor_fit', 'prediction_used', 'search_widened',
                   'other_basin')
"""Counted events of the evidence a match had: its covariance grew along a direction
the scan hardly constrains (``weakly_constrained``) or, as no searched pose fitted
well, to the whole window (``poor_fit``); the window was searched again twice as wide
(``search_widened``); from a start moved a little off the prediction the matcher
stopped elsewhere, and the covariance covers that pose (``other_basin``,
:mod:`laser_odom.core.registration.basins`)."""


def say_why(events: EventLog, registration: Registration, verdict: MatchVerdict,
            guess: se2.Pose, stamp_ns: int, config: PipelineConfig) -> None:
    """Count and say (throttled) the global search, ambiguity and rejection, with numbers."""
    at = f't={stamp_ns * 1e-9:.3f}'
    match = registration.match
    trigger = registration.trigger
    if trigger in ROUTINE_TRIGGERS:
        events.count(f'search_{trigger}')
    elif trigger:
        why = SEARCH_TRIGGERS[trigger]
        if registration.local_failure:
            why += f' ({registration.failure_detail})'
        events.warn(f'search_{trigger}', f'global search at {at}: {why}; '
                    f'{registration.outcome(guess)}')
    if verdict.status == 'rejected':
        reason = match.extra.get('rejection', 'unknown')
        if config.acceptance.rejected_motion != 'predict':
            action = 'holding the pose'
        elif config.motion.prior == 'none':
            action = 'holding the pose (prior none: no prediction to advance by)'
        else:
            action = 'advancing by the prediction'
        detail = describe_rejection(reason, match, guess, config)
        searched = (f'; the global search ran ({SEARCH_TRIGGERS[trigger]}) and found '
                    f'{registration.outcome(guess)}'
                    if trigger in ROUTINE_TRIGGERS else '')
        events.warn('rejected_' + reason, f'match at {at} rejected ({detail}){searched}; {action}')
    elif registration.alternatives:
        events.warn('ambiguous', f'match at {at} is ambiguous: '
                    f'{registration.describe_alternatives()}; reported degenerate '
                    'with a covariance that covers the alternatives')


def say_evidence(events: EventLog, registration: Registration, status: str, at: str) -> None:
    """Count and say (throttled) what the evidence made of an integrated match."""
    match = registration.match
    if registration.widened:
        events.count('search_widened')
    if status != 'rejected' and match.extra.get('predicted'):
        events.warn('prediction_used', f'match at {at} is blind along a direction; '
                    f'{PREDICTION_SOURCES[match.extra["predicted"]]} stands in there, '
                    'with its measured error as the covariance')
    if status != 'rejected' and match.extra.get('poor_fit'):
        window = registration.window
        events.warn('poor_fit', f'match at {at} fits poorly (surface fit '
                    f'{match.extra["surface_fit"]:.2f}, the best pose in '
                    f'+-{window.linear:.1f} m / +-{math.degrees(window.angular):.0f}'
                    ' deg): its covariance covers the window')
    elif status != 'rejected' and match.extra.get('weak'):
        sigma = np.sqrt(np.linalg.eigvalsh(match.extra['surface_covariance'])[-1])
        events.warn('weakly_constrained', f'match at {at} is weakly constrained: '
                    f'poses up to {sigma:.2f} m away (1 sigma) fit about as '
                    'well; its covariance covers them')
