#!/bin/bash
# The C++ sources are as clang-format (.clang-format) writes them: run
#   git ls-files '*.cpp' '*.h' | xargs clang-format -i
# to format. Skipped (77) where clang-format is not installed or the tree is not a git checkout.
set -euo pipefail
src=${1:?usage: format_check.sh SOURCE_DIR}
if ! command -v clang-format > /dev/null || ! git -C "$src" rev-parse --git-dir > /dev/null 2>&1; then
  echo "format_check: clang-format or git missing; skipped"
  exit 77
fi
cd "$src"
if ! git ls-files -z '*.cpp' '*.h' | xargs -0 clang-format --dry-run -Werror 2> /tmp/format_check.$$; then
  grep -m 20 "error:" /tmp/format_check.$$ >&2 || true
  rm -f /tmp/format_check.$$
  echo "format_check: sources differ from .clang-format's output; run: git ls-files '*.cpp' '*.h' | xargs clang-format -i" >&2
  exit 1
fi
rm -f /tmp/format_check.$$
echo "format_check: every source formatted"
