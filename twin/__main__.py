"""``python -m twin``: the ``twin`` command (the same as the console script)."""
from twin.cli import main

if __name__ == "__main__":
    main(prog_name="twin")
