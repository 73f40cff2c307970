"""VIRL: a recurrent Siamese comparator of the agent's and the demonstration's sequences (states or video) as a
reward."""
