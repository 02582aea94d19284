"""``python -m stscam ARGS`` runs the ``stscam`` command line."""
from .cli import main

if __name__ == "__main__":
    main()
