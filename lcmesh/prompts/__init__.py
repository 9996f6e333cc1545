"""Prompt templates (package data): explanation levels, controller I/O, chat."""
