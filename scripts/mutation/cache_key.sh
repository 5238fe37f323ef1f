# shellcheck shell=bash disable=SC2034
# The cache-key functions of wbmpc/solver/codegen.py, ~15 min on one core.
module="wbmpc/solver/codegen.py"
tests=(tests/test_codegen.py)
select="cache_key or same_key or canonical or fingerprint or urdf"
names=('wbmpc.solver.codegen.x__number_*' 'wbmpc.solver.codegen.x__rounded_*'
       'wbmpc.solver.codegen.x__numbers_*' 'wbmpc.solver.codegen.x__placement_*'
       'wbmpc.solver.codegen.x_model_fingerprint_*' 'wbmpc.solver.codegen.x__digest_*'
       'wbmpc.solver.codegen.x_cache_key_*')
