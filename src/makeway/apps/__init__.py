"""Applications built on the stages: the demo, closed-loop runs with their reports, evaluation runs.

Each app composes pipelines, metrics and plots into one call the command line makes
(``makeway demo``, ``makeway simulate``); nothing below ``apps`` imports from here.
"""
