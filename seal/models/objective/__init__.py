"""SEAL's learned objective pi_score (thesis 6.3.1): predicts f_coll and f_diff of a candidate adversary future
against a previous ego roll-out; candidates are ranked by the mean over the K past roll-outs of the sum.

Core package: numpy and torch only. Labels are simulated by ``seal.experiments.fitting.objective_labels`` and the
whole job
is ``seal fit objective`` (``seal.experiments.fitting.objective``).
"""

from seal.models.objective.features import FEATURE_NAMES, align_ego_rollouts, pair_features
from seal.models.objective.labels import LOGGED_ROW, LabelSet
from seal.models.objective.model import ObjectiveFileError, ObjectiveModel
from seal.models.objective.network import ObjectiveConfig, ObjectiveNet
from seal.models.objective.train import FitResult, ObjectiveTrainConfig, train_objective

__all__ = [
    "FEATURE_NAMES", "LOGGED_ROW", "FitResult", "LabelSet", "ObjectiveConfig", "ObjectiveFileError", "ObjectiveModel",
    "ObjectiveNet", "ObjectiveTrainConfig", "align_ego_rollouts", "pair_features", "train_objective",
]
