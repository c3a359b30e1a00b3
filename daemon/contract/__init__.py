"""The contract: wire messages, profile schema, hardware interfaces, plugin base classes and
geometry; it imports nothing else of climbd."""
