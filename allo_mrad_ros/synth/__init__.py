"""ALLO-like sequence generator: ``allo-synth generate`` and ``allo-synth import-allo``."""
