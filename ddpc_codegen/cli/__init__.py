"""argparse front ends of the ``ddpc-codegen`` command (:mod:`.main` dispatches to the others)."""
