# Sourced by .ci/run and the scripts it calls: every CI block prints its name when it starts
# and its duration when it ends, in one format, so a slow run can be attributed:
#
#   == NAME
#   ...
#   (NAME: N s)
#
# `ci_block NAME` ends the current block (if any) and starts NAME; `ci_block_end` ends it (the
# EXIT trap set here does that too, so a failing block still prints its duration; a script
# with its own EXIT trap calls ci_block_end from it).

# ci_block NAME: end the current block, start NAME.
ci_block() {
    ci_block_end
    _ci_block_name=$1
    _ci_block_t0=$SECONDS
    echo "== $1"
}

# ci_block_end: print the current block's duration (nothing if none is open).
ci_block_end() {
    if [ -n "${_ci_block_name:-}" ]; then
        echo "(${_ci_block_name}: $((SECONDS - _ci_block_t0)) s)"
        _ci_block_name=
    fi
}

trap ci_block_end EXIT
