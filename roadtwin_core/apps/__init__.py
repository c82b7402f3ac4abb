"""What each command does with the framework: orchestration, file outputs, plots (one subpackage
per command, small modules with one concern each). ``cli*.py`` only parse options and call these."""
