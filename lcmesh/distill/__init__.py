"""Policy distillation: PPO teacher, experience with VIPER weights, trees, the LLM."""
