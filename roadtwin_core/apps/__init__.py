"""What the commands do: one package per command (``apps/sweep``, ``apps/render``, ``apps/plan``),
small modules of one concern each (run matrix, output files, plots, dataset writers...).

Apps import the framework (``roadtwin_core`` and its public subpackages); the framework never
imports an app. The command line (``roadtwin_core/cli/``) parses options and calls an app.
"""
