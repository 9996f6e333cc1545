"""The math toolbox: pure functions the agents and explanations cite, plus guardrails and explanation scoring."""
