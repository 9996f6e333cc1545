"""The chat question set (``chat_questions.jsonl``): held-out dev and test questions for ``lcmesh bench chat``."""
