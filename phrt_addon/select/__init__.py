"""The selection: the paper's terms, graph and greedy pass, the cost model and budget loop, budgets between modes, benefit."""
