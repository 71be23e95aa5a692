"""One QgsProcessingAlgorithm per file: parameters, help, progress, cancellation, one engine call."""
