"""The book: pages, notebook execution, the build, the protocol table, videos and a user's agent."""
