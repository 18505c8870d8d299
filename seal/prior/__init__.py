"""The trajectory prior pi_gen: multimodal candidate futures for an agent (used by CAT, SEAL and later generators)."""

from seal.prior.candidates import Candidates

__all__ = ["Candidates"]
