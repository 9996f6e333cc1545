"""LLM backends (local transformers model or an OpenAI-compatible endpoint) and the LLM controller."""
