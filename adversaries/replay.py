"""``replay``: the logged adversary, unperturbed (the reference every other generator is compared with)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from seal.adversaries.base import AdversaryGenerator, Generation, register
from seal.core.scenario import Scenario
from seal.envs.behaviors import ReplayBehavior
from seal.envs.rollout import Rollout


@register("replay")
class ReplayGenerator(AdversaryGenerator):
    """Returns the adversary's logged track; ignores the roll-out history."""

    def _generate(self, scenario: Scenario, history: Sequence[Rollout], rng: np.random.Generator) -> Generation:
        return Generation(behavior=ReplayBehavior(scenario.track(scenario.adv_id)))
