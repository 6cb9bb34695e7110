"""OP3 humanoid locomotion domain (paper Sec. 5, App. C; docs/locomotion.md). Needs the extra
``locomotion`` (the OP3 assets): ``pip install -e ".[locomotion]"``."""
