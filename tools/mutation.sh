#!/bin/bash
# Mutation testing of the curriculum, the closed-loop queue, CAT / SEAL selection, resume, the restricted
# unpickler and the safe SB3 model loader (issue 24). A dev tool, not run in CI:
# pip install -e ".[test,mutation]" (mutmut 2.5.1).
#
# mutmut rewrites the source files in place, one mutant at a time: run this in a copy of the checkout with its own
# editable install, never in a working tree you are editing (README.md, "Mutation testing"). Results accumulate in
# .mutmut-cache; a second run re-tests only the survivors (killed mutants stay killed) when the tests changed.
set -u
cd "$(dirname "$0")/.."
PY=${PYTHON:-.venv/bin/python}
RUN="$PY tools/mutation_runner.py test"
$PY tools/mutation_runner.py serve > .mutmut-runner.log 2>&1 &
until grep -q ready .mutmut-runner.log 2>/dev/null; do sleep 1; done
group() {  # FILE TESTS...: mutate FILE, judge each mutant with pytest over TESTS (in the warm runner)
  local path=$1; shift
  echo "=== $path"
  nice -n 10 $PY -m mutmut run --paths-to-mutate "$path" --tests-dir tests/ --runner "$RUN $*" \
    --simple-output --no-progress > /dev/null 2>&1
}
NOT_SLOW="-k 'not resume and not safe_loader'"
group experiments/training/curriculum.py tests/experiments/test_curriculum.py tests/adversaries/test_history.py \
  tests/experiments/test_train_faults.py "$NOT_SLOW"
group adversaries/closed_loop.py tests/adversaries/test_history.py tests/experiments/test_curriculum.py \
  tests/experiments/test_train_faults.py tests/adversaries/test_closed_loop.py "$NOT_SLOW"
group adversaries/history.py tests/adversaries/test_history.py tests/experiments/test_train.py -k history
group adversaries/cat/select.py tests/adversaries/test_generators_cat.py tests/adversaries/test_candidate_generator.py \
  tests/adversaries/test_cat_select.py
group adversaries/seal/generator.py tests/adversaries/test_generators_seal.py tests/adversaries/test_candidate_generator.py
group seal/core/importers/safe_pickle.py tests/core/test_import_scenarionet.py \
  tests/core/test_import_scenarionet_repairs.py tests/core/test_safe_pickle.py
group experiments/training/state.py tests/experiments/test_train.py tests/experiments/test_train_checkpoints.py \
  tests/experiments/test_train_state.py tests/experiments/test_train_state_restore.py \
  tests/experiments/test_train_state_files.py -k "'history_state or replay_buffer or truncate_progress or run_folder \
  or train_state or (checkpoint and not killed and not corrupt_latest and not damaged_checkpoint_file)'"
group experiments/training/sb3_load.py tests/experiments/test_sb3_load_files.py tests/experiments/test_sb3_load_checks.py \
  tests/experiments/test_sb3_vecnormalize.py tests/experiments/test_byo_ego.py tests/experiments/test_train_faults.py \
  tests/adversaries/test_generators_eval.py -k "'sb3 or byo or safe_loader'"
$PY tools/mutation_runner.py stop
$PY tools/mutation_score.py .mutmut-cache
