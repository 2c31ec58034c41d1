"""``python -m meshadv``: the same as the ``meshadv`` command."""

from meshadv.cli import main

if __name__ == "__main__":
    main()
