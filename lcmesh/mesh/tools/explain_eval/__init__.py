"""``lcmesh explain-eval``: score explanations of control actions from any system.

Input: JSON lines ``{"id", "observation", "action", "explanation", "facts"?, "previous_action"?,
"level"?, "index_base"?}`` (DESIGN.md, CLI). Output: ``{"items": [{"id", "numeric_grounding",
"coverage", "direction_consistency", "flags": [{"kind", "detail"}], "claims": [...], ...}], "aggregate": {...}}``.

Flag kinds (``lcmesh.mesh.tools.claims.FLAG_KINDS``, shared with the chat's guard and the LLM explainer):
``ungrounded_number``, ``missing_action_dimension``, ``wrong_direction``, ``wrong_ranking``, ``out_of_bounds``,
``physics``, ``missing_section`` (when the record names its ``level``), ``invalid_record`` (a line that is not a
valid record: reported with its line number, scored 0 and left out of the aggregate; the run goes on) and
``not_read`` (a text in a language no reader covers: reported, left out of the aggregate, never passed or flagged).

The judge is ``judge.py``; the rules are in docs/explanations.md.
"""

from lcmesh.mesh.tools.claims import FLAG_KINDS
from lcmesh.mesh.tools.explain_eval.judge import LEVEL_SECTIONS, evaluate_file, evaluate_lines, evaluate_record
from lcmesh.mesh.tools.explain_eval.record import EvalConfig
from lcmesh.mesh.tools.explain_eval.report import render_markdown

__all__ = ["EvalConfig", "FLAG_KINDS", "LEVEL_SECTIONS", "evaluate_file", "evaluate_lines", "evaluate_record",
           "render_markdown"]  # fmt: skip
