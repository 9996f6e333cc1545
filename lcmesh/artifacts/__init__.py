"""Trained artifacts shipped with the package: PPO policies, distilled trees, the LLM adapter (each with a manifest)."""
