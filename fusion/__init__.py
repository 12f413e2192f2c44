"""Navigation fusion: INS + DVL dead reckoning, time alignment, frames and lever arms."""
