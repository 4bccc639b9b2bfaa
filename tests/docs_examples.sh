#!/bin/bash
# The worked examples of the docs still apply to this source tree: docs/examples/*.patch
# (docs/architecture.md, "Adding a pass"). A patch that no longer applies fails with its name:
# rebuild it on the current code (apply it by hand, fix, git diff > the patch). Skipped (77)
# where the tree is not a git checkout.
set -euo pipefail
src=${1:?usage: docs_examples.sh SOURCE_DIR}
if ! git -C "$src" rev-parse --git-dir > /dev/null 2>&1; then
  echo "docs_examples: $src is not a git checkout; skipped"
  exit 77
fi
shopt -s nullglob
patches=("$src"/docs/examples/*.patch)
if [ ${#patches[@]} -eq 0 ]; then
  echo "docs_examples: no patches in $src/docs/examples" >&2
  exit 1
fi
for p in "${patches[@]}"; do
  if ! git -C "$src" apply --check "$p"; then
    echo "docs_examples: $p no longer applies to $src: rebuild it (see docs/architecture.md, \"Adding a pass\")" >&2
    exit 1
  fi
  echo "docs_examples: $(basename "$p") applies"
done
