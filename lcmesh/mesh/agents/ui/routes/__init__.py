"""The UI agent's routes: reads (read.py), authenticated writes (control.py), chat (chat.py), live events (stream.py)."""
