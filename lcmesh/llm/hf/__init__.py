"""The transformers side of the LLM: the only modules importing transformers, peft, bitsandbytes and gguf.

``unpack`` turns the shipped GGUF into a safetensors folder, ``backend`` loads and generates (batched
greedy, and draft-verified decoding for long texts), ``train`` runs QLoRA / LoRA fine-tuning.
"""
