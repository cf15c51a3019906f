"""Networks and datasets shared by rl/ and supervised/; the agents, dataset collection and the shipped navigators on top."""
