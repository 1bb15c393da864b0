"""Synthetic captures with ground truth (`handloop synth`): subjects, motion, forearm and held objects,
backgrounds, compositing with green spill, chroma key, visibility, and the parallel generator.

Entry points: `workers.synth.plan.SynthConfig`, `workers.synth.generator.generate_capture` and
`workers.synth.generator.FrameRenderer` (renders frames without writing them). The package imports
none of its modules, so importing it stays cheap.
"""
