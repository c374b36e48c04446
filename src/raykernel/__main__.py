"""`python -m raykernel ...`: the `raykernel` command."""

from .cli import run

if __name__ == "__main__":
    run()
