"""python3 -m dhrbench_results DIR: a short summary of a results folder (experiments/ on
PYTHONPATH); exit 2 with one line naming the file and the field when it is damaged."""
import sys

from . import BadResults, load, summary


def main(argv):
    if len(argv) != 2:
        print("usage: python3 -m dhrbench_results RESULTS_DIR", file=sys.stderr)
        return 2
    try:
        print(summary(load(argv[1])))
    except BadResults as e:
        print(f"dhrbench_results: error: {e}", file=sys.stderr)
        return 2
    except ImportError as e:
        print(f"dhrbench_results: error: {e}", file=sys.stderr)
        return 3
    return 0


sys.exit(main(sys.argv))
